"""σ, φ and ψ on torch_geometric graphs (the reference implementation of :class:`~.graph.StageGraphs`): each
subgraph of :mod:`.graph` built as a ``HeteroData`` of edge lists with one attribute per edge, run through PyG's
``TransformerConv`` layers (:meth:`~.graph_transformer.HeteroGraphTransformer.forward`).

Connectivity depends only on the sizes (B, N, L, T, M) and is built once per size and device (``lru_cache``),
never as inference tensors, so a graph first built at inference can serve training.
Node ``k`` of local graph ``g`` has index ``g · G + k`` (G gripper keypoints; scene nodes ``g · M + m``); graphs are
ordered sample-major: demo frame ``(b, n, l)`` is ``(b · N + n) · L + l``, action frame ``(b, i)`` is ``b · T + i``,
current frame ``b``.
"""

from __future__ import annotations

import functools

import torch
from torch_geometric.data import HeteroData

from ..geometry.rigid_torch import full_precision
from .encodings import sinusoidal_encoding
from .graph import (
    ACTION,
    ACTION_TO_ACTION,
    CURRENT,
    CURRENT_TO_ACTION,
    DEMO,
    DEMO_TIME,
    DEMO_TO_CURRENT,
    GRIPPER,
    GRIPPER_TO_GRIPPER,
    SCENE,
    SCENE_TO_GRIPPER,
    SCENE_TO_SCENE,
    StageGraphs,
)


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
    batch_size: int, num_demos: int, demo_length: int, num_keypoints: int, device: torch.device
) -> HeteroData:
    """Connectivity of φ's graph: demo waypoint ``l+1`` → ``l`` and all demo gripper nodes → current gripper nodes."""
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


def keypoint_offset_attr(store, keypoints: torch.Tensor, num_frequencies: int) -> torch.Tensor:
    """``enc(k_dst − k_src)`` per edge, both keypoints in the gripper frame (edges between different worlds)."""
    return sinusoidal_encoding(keypoints[store.dst_keypoint] - keypoints[store.src_keypoint], num_frequencies)


class SparseGraphs(StageGraphs):
    """:class:`~.graph.StageGraphs` on torch_geometric graphs: node tensors flattened to one row per node, edge
    attributes gathered per edge of the cached connectivity."""

    def local(
        self, scene_positions: torch.Tensor, scene_nodes: torch.Tensor, gripper_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        num_graphs, num_scene = scene_positions.shape[:2]
        graph = local_graph(num_graphs, num_scene, len(keypoints), scene_positions.device)
        scene_flat = scene_positions.reshape(-1, 3)
        gripper_flat = keypoints.repeat(num_graphs, 1)
        frequencies = self.num_frequencies
        edge_attr = {
            SCENE_TO_SCENE: position_attr(scene_flat, scene_flat, graph[SCENE_TO_SCENE].edge_index, frequencies),
            SCENE_TO_GRIPPER: position_attr(scene_flat, gripper_flat, graph[SCENE_TO_GRIPPER].edge_index, frequencies),
            GRIPPER_TO_GRIPPER: position_attr(
                gripper_flat, gripper_flat, graph[GRIPPER_TO_GRIPPER].edge_index, frequencies
            ),
        }
        x = {
            SCENE: scene_nodes.reshape(-1, scene_nodes.shape[-1]),
            GRIPPER: gripper_nodes.reshape(-1, gripper_nodes.shape[-1]),
        }
        return self.local_network(x, graph.edge_index_dict, edge_attr)[GRIPPER].view(gripper_nodes.shape)

    def context(
        self, T_world_ee: torch.Tensor, demo_nodes: torch.Tensor, current_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        batch, num_demos, demo_length = T_world_ee.shape[:3]
        graph = context_graph(batch, num_demos, demo_length, len(keypoints), T_world_ee.device)
        demo_frames = T_world_ee.reshape(-1, 4, 4)
        frequencies = self.num_frequencies
        edge_attr = {
            DEMO_TIME: transform_attr(demo_frames, demo_frames, graph[DEMO_TIME], keypoints, frequencies),
            DEMO_TO_CURRENT: keypoint_offset_attr(graph[DEMO_TO_CURRENT], keypoints, frequencies),
        }
        x = {
            DEMO: demo_nodes.reshape(-1, demo_nodes.shape[-1]),
            CURRENT: current_nodes.reshape(-1, current_nodes.shape[-1]),
        }
        return self.context_network(x, graph.edge_index_dict, edge_attr)[CURRENT].view(current_nodes.shape)

    def actions(
        self, T_ee_actions: torch.Tensor, current_nodes: torch.Tensor, action_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        batch, horizon = T_ee_actions.shape[:2]
        graph = action_graph(batch, horizon, len(keypoints), T_ee_actions.device)
        current_frames = torch.eye(4, dtype=T_ee_actions.dtype, device=T_ee_actions.device).expand(batch, 4, 4)
        action_frames = T_ee_actions.reshape(-1, 4, 4)
        frequencies = self.num_frequencies
        edge_attr = {
            CURRENT_TO_ACTION: transform_attr(
                current_frames, action_frames, graph[CURRENT_TO_ACTION], keypoints, frequencies
            ),
            ACTION_TO_ACTION: transform_attr(action_frames, action_frames, graph[ACTION_TO_ACTION], keypoints, frequencies),
        }
        x = {
            CURRENT: current_nodes.reshape(-1, current_nodes.shape[-1]),
            ACTION: action_nodes.reshape(-1, action_nodes.shape[-1]),
        }
        return self.action_network(x, graph.edge_index_dict, edge_attr)[ACTION].view(action_nodes.shape)
