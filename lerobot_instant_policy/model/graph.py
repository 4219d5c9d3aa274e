"""The heterogeneous graph of Instant Policy (paper §3.1, docs/design.md §5): node and edge layout, edge attributes.

A *local graph* is one time step seen from its own end-effector frame: ``M`` scene nodes (geometry-encoder
centroids of the cloud expressed in that frame) and ``K = 6`` gripper nodes at fixed keypoints of the gripper.
Per sample there are ``N · L`` demonstration local graphs, one current local graph and ``T`` action local graphs.
The networks see three subgraphs, each a ``torch_geometric`` :class:`HeteroData`:

- local (σ): node types ``scene``, ``gripper``; edges scene→scene, scene→gripper and gripper→gripper inside every
  local graph (no self loops);
- context (φ): node types ``demo`` and ``current`` (the gripper nodes of the demonstration and current local
  graphs); edges demo waypoint ``l+1`` → ``l`` (every keypoint pair) and every demo gripper node of a sample →
  every current gripper node of that sample; with ``context_scene_edges`` also node type ``scene`` (the current
  local graph's scene nodes) and edges scene → current, so that what the current nodes read of the live scene can
  depend on the demonstrations (σ reads it before any context is seen);
- action (ψ): node types ``current`` and ``action``; edges current → every action gripper node, and action ``i`` →
  action ``j`` for ``i ≠ j`` (every keypoint pair).

Edge attributes: inside a local graph (and φ's scene → current edges, in the current EE frame), ``enc(p_dst − p_src)`` (sin/cos at ``2⁰π … 2⁹π`` plus the raw vector).
Between frames of one world (demo time edges, current → action, action → action), the attribute describes the
relative transform ``T_src,dst = T_src⁻¹ T_dst = (R, t)``: ``[enc(t), enc(R k − k)]`` with ``k`` the destination's
keypoint, i.e. the translation and the displacement that the rotation gives that keypoint. Demonstrations and the
current observation live in different worlds, so demo → current edges carry ``enc(k_dst − k_src)`` in the gripper
frame. Every attribute is relative, so moving a whole world rigidly changes none of them.

Connectivity depends only on the sizes (B, N, L, T, M) and is built once per size and device (``lru_cache``),
never as inference tensors, so a graph first built at inference can serve training.
Node ``k`` of local graph ``g`` has index ``g · G + k`` (G gripper keypoints; scene nodes ``g · M + m``); graphs are
ordered sample-major: demo frame ``(b, n, l)`` is ``(b · N + n) · L + l``, action frame ``(b, i)`` is ``b · T + i``, current frame ``b``.
"""

from __future__ import annotations

import functools

import torch
from torch_geometric.data import HeteroData

from ..geometry.rigid_torch import full_precision
from .encodings import encoding_dim, sinusoidal_encoding

SCENE, GRIPPER, DEMO, CURRENT, ACTION = "scene", "gripper", "demo", "current", "action"
SCENE_TO_SCENE = (SCENE, "local", SCENE)
SCENE_TO_GRIPPER = (SCENE, "local", GRIPPER)
GRIPPER_TO_GRIPPER = (GRIPPER, "local", GRIPPER)
DEMO_TIME = (DEMO, "time", DEMO)
DEMO_TO_CURRENT = (DEMO, "context", CURRENT)
SCENE_TO_CURRENT = (SCENE, "local", CURRENT)
CURRENT_TO_ACTION = (CURRENT, "plan", ACTION)
ACTION_TO_ACTION = (ACTION, "plan", ACTION)
EdgeType = tuple[str, str, str]


def position_dim(num_frequencies: int) -> int:
    """Width of a position attribute ``enc(v)``."""
    return encoding_dim(3, num_frequencies)


def transform_dim(num_frequencies: int) -> int:
    """Width of a relative-transform attribute ``[enc(t), enc(R k − k)]``."""
    return 2 * encoding_dim(3, num_frequencies)


def local_edge_dims(num_frequencies: int) -> dict[EdgeType, int]:
    return {edge_type: position_dim(num_frequencies) for edge_type in (SCENE_TO_SCENE, SCENE_TO_GRIPPER, GRIPPER_TO_GRIPPER)}


def context_edge_dims(num_frequencies: int, scene_edges: bool = False) -> dict[EdgeType, int]:
    dims = {DEMO_TIME: transform_dim(num_frequencies), DEMO_TO_CURRENT: position_dim(num_frequencies)}
    if scene_edges:
        dims[SCENE_TO_CURRENT] = position_dim(num_frequencies)
    return dims


def action_edge_dims(num_frequencies: int) -> dict[EdgeType, int]:
    return {CURRENT_TO_ACTION: transform_dim(num_frequencies), ACTION_TO_ACTION: transform_dim(num_frequencies)}


def _all_pairs(num_src: int, num_dst: int, without_diagonal: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    src, dst = torch.meshgrid(torch.arange(num_src), torch.arange(num_dst), indexing="ij")
    src, dst = src.flatten(), dst.flatten()
    if without_diagonal:
        keep = src != dst
        src, dst = src[keep], dst[keep]
    return src, dst


def _frame_pair_edges(src_frame: torch.Tensor, dst_frame: torch.Tensor, num_keypoints: int) -> dict[str, torch.Tensor]:
    """Every keypoint of frame ``src_frame[i]`` → every keypoint of ``dst_frame[i]``, with per-edge frame bookkeeping."""
    src_keypoint, dst_keypoint = _all_pairs(num_keypoints, num_keypoints)
    pairs = len(src_frame)
    src_frame = src_frame.repeat_interleave(len(src_keypoint))
    dst_frame = dst_frame.repeat_interleave(len(dst_keypoint))
    src_keypoint, dst_keypoint = src_keypoint.repeat(pairs), dst_keypoint.repeat(pairs)
    return {
        "edge_index": torch.stack([src_frame * num_keypoints + src_keypoint, dst_frame * num_keypoints + dst_keypoint]),
        "src_frame": src_frame,
        "dst_frame": dst_frame,
        "dst_keypoint": dst_keypoint,
    }


def _to(graph: HeteroData, device: torch.device) -> HeteroData:
    return graph.to(device) if device.type != "cpu" else graph


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def local_graph(num_graphs: int, num_scene: int, num_keypoints: int, device: torch.device) -> HeteroData:
    """Connectivity of ``num_graphs`` local graphs of ``num_scene`` scene and ``num_keypoints`` gripper nodes."""
    graph = HeteroData()
    graph[SCENE].num_nodes = num_graphs * num_scene
    graph[GRIPPER].num_nodes = num_graphs * num_keypoints
    offsets = torch.arange(num_graphs)
    for edge_type, num_src, num_dst, without_diagonal in (
        (SCENE_TO_SCENE, num_scene, num_scene, True),
        (SCENE_TO_GRIPPER, num_scene, num_keypoints, False),
        (GRIPPER_TO_GRIPPER, num_keypoints, num_keypoints, True),
    ):
        src, dst = _all_pairs(num_src, num_dst, without_diagonal)
        src = (offsets[:, None] * num_src + src).flatten()
        dst = (offsets[:, None] * num_dst + dst).flatten()
        graph[edge_type].edge_index = torch.stack([src, dst])
    return _to(graph, device)


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def context_graph(
    batch_size: int, num_demos: int, demo_length: int, num_keypoints: int, device: torch.device, num_scene: int = 0
) -> HeteroData:
    """Connectivity of φ's graph: demo waypoint ``l+1`` → ``l`` and all demo gripper nodes → current gripper nodes;
    with ``num_scene > 0`` also the ``num_scene`` scene nodes of each sample's current frame → its current nodes."""
    graph = HeteroData()
    graph[DEMO].num_nodes = batch_size * num_demos * demo_length * num_keypoints
    graph[CURRENT].num_nodes = batch_size * num_keypoints
    frames = torch.arange(batch_size * num_demos * demo_length).view(batch_size * num_demos, demo_length)
    for key, value in _frame_pair_edges(frames[:, 1:].flatten(), frames[:, :-1].flatten(), num_keypoints).items():
        graph[DEMO_TIME][key] = value
    demo_nodes_per_sample = num_demos * demo_length * num_keypoints
    src, dst = _all_pairs(demo_nodes_per_sample, num_keypoints)
    samples = torch.arange(batch_size)[:, None]
    graph[DEMO_TO_CURRENT].edge_index = torch.stack(
        [(samples * demo_nodes_per_sample + src).flatten(), (samples * num_keypoints + dst).flatten()]
    )
    graph[DEMO_TO_CURRENT].src_keypoint = (src % num_keypoints).repeat(batch_size)
    graph[DEMO_TO_CURRENT].dst_keypoint = dst.repeat(batch_size)
    if num_scene:
        graph[SCENE].num_nodes = batch_size * num_scene
        src, dst = _all_pairs(num_scene, num_keypoints)
        graph[SCENE_TO_CURRENT].edge_index = torch.stack(
            [(samples * num_scene + src).flatten(), (samples * num_keypoints + dst).flatten()]
        )
    return _to(graph, device)


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def action_graph(batch_size: int, horizon: int, num_keypoints: int, device: torch.device) -> HeteroData:
    """Connectivity of ψ's graph: current → every action, action ``i`` → action ``j ≠ i``.

    Frames: the current frame of sample ``b`` is ``b``; action ``i`` of sample ``b`` is ``b · T + i``.
    """
    graph = HeteroData()
    graph[CURRENT].num_nodes = batch_size * num_keypoints
    graph[ACTION].num_nodes = batch_size * horizon * num_keypoints
    current = torch.arange(batch_size).repeat_interleave(horizon)
    actions = torch.arange(batch_size * horizon)
    for key, value in _frame_pair_edges(current, actions, num_keypoints).items():
        graph[CURRENT_TO_ACTION][key] = value
    src, dst = _all_pairs(horizon, horizon, without_diagonal=True)
    samples = torch.arange(batch_size)[:, None] * horizon
    src_frame, dst_frame = (samples + src).flatten(), (samples + dst).flatten()
    for key, value in _frame_pair_edges(src_frame, dst_frame, num_keypoints).items():
        graph[ACTION_TO_ACTION][key] = value
    return _to(graph, device)


def position_attr(
    src_positions: torch.Tensor, dst_positions: torch.Tensor, edge_index: torch.Tensor, num_frequencies: int
) -> torch.Tensor:
    """``enc(p_dst − p_src)`` per edge: positions ``(S, 3)``, ``(D, 3)`` in one frame, ``edge_index (2, E)`` → ``(E, ·)``."""
    return sinusoidal_encoding(dst_positions[edge_index[1]] - src_positions[edge_index[0]], num_frequencies)


@full_precision()
def transform_attr(
    src_frames: torch.Tensor,
    dst_frames: torch.Tensor,
    store,
    keypoints: torch.Tensor,
    num_frequencies: int,
) -> torch.Tensor:
    """``[enc(t), enc(R k − k)]`` of ``T_src,dst = T_src⁻¹ T_dst`` per edge.

    Args:
        src_frames: ``(F_src, 4, 4)`` poses of the source frames in a common frame (the world or the EE frame).
        dst_frames: ``(F_dst, 4, 4)`` poses of the destination frames in the same frame.
        store: the edge store of a graph built here (``src_frame``, ``dst_frame``, ``dst_keypoint`` per edge).
        keypoints: ``(G, 3)`` gripper keypoints.
    """
    T_src = src_frames[store.src_frame]
    T_dst = dst_frames[store.dst_frame]
    R_src_t = T_src[:, :3, :3].transpose(-1, -2)
    R = R_src_t @ T_dst[:, :3, :3]
    t = (R_src_t @ (T_dst[:, :3, 3] - T_src[:, :3, 3])[..., None]).squeeze(-1)
    keypoint = keypoints[store.dst_keypoint]
    displacement = (R @ keypoint[..., None]).squeeze(-1) - keypoint
    return torch.cat([sinusoidal_encoding(t, num_frequencies), sinusoidal_encoding(displacement, num_frequencies)], -1)


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def dense_local_masks(num_scene: int, num_keypoints: int, device: torch.device) -> dict[EdgeType, torch.Tensor | None]:
    """:func:`local_graph`'s connectivity in the dense layout: edge type → ``(n_src, n_dst)`` bool (``None``: all
    pairs); no self loops."""
    return {
        SCENE_TO_SCENE: ~torch.eye(num_scene, dtype=torch.bool, device=device),
        SCENE_TO_GRIPPER: None,
        GRIPPER_TO_GRIPPER: ~torch.eye(num_keypoints, dtype=torch.bool, device=device),
    }


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def dense_action_masks(horizon: int, num_keypoints: int, device: torch.device) -> dict[EdgeType, torch.Tensor | None]:
    """:func:`action_graph`'s connectivity in the dense layout: current → every action node, action ``i`` → action
    ``j ≠ i`` (node ``i · G + k``)."""
    other_frame = ~torch.eye(horizon, dtype=torch.bool, device=device)
    return {
        CURRENT_TO_ACTION: None,
        ACTION_TO_ACTION: other_frame.repeat_interleave(num_keypoints, 0).repeat_interleave(num_keypoints, 1),
    }


class DenseLayout:
    """How one edge type's ``G`` graphs of the dense layout are read from its node types' tensors: as they are,
    ``(G, n, ·)`` (σ's local graphs, ψ's graph per sample)."""

    def sources(self, x: torch.Tensor) -> torch.Tensor:
        """The source node type's tensor → ``(G, S, ·)``."""
        return x

    def destinations(self, x: torch.Tensor) -> torch.Tensor:
        """The destination node type's tensor → ``(G, D, ·)``."""
        return x

    def scatter(self, update: torch.Tensor, destination: torch.Tensor) -> torch.Tensor:
        """The attention's ``(G, D, ·)`` → the layout of the destination node type's tensor ``destination``."""
        return update


class NextWaypointLayout(DenseLayout):
    """φ's time edges in the dense layout: demo nodes ``(B, N, L, G, ·)``; every keypoint of waypoint ``l + 1`` →
    every keypoint of waypoint ``l`` of the same demonstration is one graph of ``G`` sources and ``G`` destinations
    (``B · N · (L − 1)`` graphs). The last waypoint receives no time edge: its attention is zero, as the
    torch-geometric layer's sum over no edges."""

    def sources(self, x: torch.Tensor) -> torch.Tensor:
        return x[:, :, 1:].flatten(0, 2)

    def destinations(self, x: torch.Tensor) -> torch.Tensor:
        return x[:, :, :-1].flatten(0, 2)

    def scatter(self, update: torch.Tensor, destination: torch.Tensor) -> torch.Tensor:
        batch, num_demos, demo_length = destination.shape[:3]
        update = update.view(batch, num_demos, demo_length - 1, *update.shape[1:])
        return torch.nn.functional.pad(update, (0, 0, 0, 0, 0, 1))


class AllWaypointsLayout(DenseLayout):
    """φ's demo → current edges in the dense layout: one graph per sample, sources the demo nodes ``(B, N, L, G, ·)``
    read as ``(B, N · L · G, ·)`` (node ``(n · L + l) · G + k``), destinations the current nodes ``(B, G, ·)``."""

    def sources(self, x: torch.Tensor) -> torch.Tensor:
        return x.flatten(1, 3)


def dense_context_layouts() -> dict[EdgeType, DenseLayout]:
    """:func:`context_graph`'s connectivity in the dense layout: every edge type's graphs (no mask needed); the
    scene → current edges are one graph per sample, scene ``(B, M, ·)`` → current ``(B, G, ·)``, as given."""
    return {DEMO_TIME: NextWaypointLayout(), DEMO_TO_CURRENT: AllWaypointsLayout(), SCENE_TO_CURRENT: DenseLayout()}


def dense_position_attr(src_positions: torch.Tensor, dst_positions: torch.Tensor, num_frequencies: int) -> torch.Tensor:
    """:func:`position_attr` of every node pair in the dense layout: ``(G, S, 3)``, ``(G, D, 3)`` →
    ``(G, S, D, ·)``, ``enc(p_dst − p_src)`` at ``[:, src, dst]``, destination-major in memory (the layout
    :func:`~.dense_attention.dense_attention` reads)."""
    offsets = dst_positions[:, :, None, :] - src_positions[:, None, :, :]  # (G, D, S, 3)
    return sinusoidal_encoding(offsets, num_frequencies).transpose(1, 2)


@full_precision()
def dense_transform_attr(
    src_frames: torch.Tensor, dst_frames: torch.Tensor, keypoints: torch.Tensor, num_frequencies: int
) -> torch.Tensor:
    """:func:`transform_attr` of every keypoint pair between frames, in the dense layout of ψ's fast path, once per
    source frame: the attribute does not depend on the source keypoint.

    Args:
        src_frames: ``(B, F_src, 4, 4)`` and ``dst_frames``: ``(B, F_dst, 4, 4)``, poses in a common frame per row.
        keypoints: ``(G, 3)`` gripper keypoints.

    Returns:
        ``(B, F_src, F_dst · G, 2 E)``: the attribute of the edges from every keypoint of source frame ``i`` to
        keypoint ``k_d`` of destination frame ``j`` at ``[:, i, j · G + k_d]``, as :func:`transform_attr` gives it on
        each of those edges; shared by the ``K`` source nodes of frame ``i`` (:func:`~.dense_attention.dense_attention`),
        destination-major in memory (the layout it reads).
    """
    batch, num_src, num_dst, num_keypoints = src_frames.shape[0], src_frames.shape[1], dst_frames.shape[1], len(keypoints)
    R_src_t = src_frames[:, None, :, :3, :3].transpose(-1, -2)  # (B, 1, F_src, 3, 3)
    R = R_src_t @ dst_frames[:, :, None, :3, :3]  # (B, F_dst, F_src, 3, 3)
    t = (R_src_t @ (dst_frames[:, :, None, :3, 3] - src_frames[:, None, :, :3, 3])[..., None]).squeeze(-1)
    displacement = (keypoints @ R.transpose(-1, -2) - keypoints).transpose(2, 3)  # (B, F_dst, G, F_src, 3): R k − k
    translation = sinusoidal_encoding(t, num_frequencies)[:, :, None].expand(-1, -1, num_keypoints, -1, -1)
    attr = torch.cat([translation, sinusoidal_encoding(displacement, num_frequencies)], dim=-1)
    return attr.view(batch, num_dst * num_keypoints, num_src, attr.shape[-1]).transpose(1, 2)


def keypoint_offset_attr(store, keypoints: torch.Tensor, num_frequencies: int) -> torch.Tensor:
    """``enc(k_dst − k_src)`` per edge, both keypoints in the gripper frame (edges between different worlds)."""
    return sinusoidal_encoding(keypoints[store.dst_keypoint] - keypoints[store.src_keypoint], num_frequencies)


def dense_keypoint_offset_attr(keypoints: torch.Tensor, num_frames: int, num_frequencies: int) -> torch.Tensor:
    """:func:`keypoint_offset_attr` of φ's demo → current edges in the dense layout of :class:`AllWaypointsLayout`:
    keypoints ``(G, 3)`` → ``(1, F · G, G, ·)``, ``enc(k_dst − k_src)`` at ``[0, f · G + k_src, k_dst]`` for each of
    the ``F = N · L`` demo frames, destination-major in memory."""
    offsets = keypoints[None, :, None, :] - keypoints[None, None, :, :]  # (1, G_dst, G_src, 3)
    return sinusoidal_encoding(offsets, num_frequencies).repeat(1, 1, num_frames, 1).transpose(1, 2)
