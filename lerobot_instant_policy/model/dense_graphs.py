"""σ, φ and ψ in a dense batched layout (the network's implementation of :class:`~.graph.StageGraphs`): every edge
type of :mod:`.graph` read as ``G`` complete bipartite graphs, all source nodes of a graph → all its destination
nodes, with a ``(n_src, n_dst)`` mask where some pairs are not edges (self loops, action ``i`` → ``i``), and run
through :meth:`~.graph_transformer.HeteroGraphTransformer.forward_dense` (:mod:`.dense_attention`): the same weights
and outputs as the torch-geometric layers of :mod:`.sparse_graphs`, without their scatter operations.

Layouts per stage: σ's ``R`` local graphs are the graphs, node tensors ``(R, M, H)`` and ``(R, G, H)``; ψ has one
graph per sample, current ``(B, G, H)`` and action nodes ``(B, T · G, H)`` (node ``i · G + k``); φ reads its demo
nodes ``(B, N, L, G, H)`` through a :class:`~.graph_transformer.DenseLayout` per edge type (one graph per pair of
consecutive waypoints, one per sample for demo → current). Edge attributes are laid out ``(G, n_src / r, n_dst, E)``,
destination-major in memory (the layout :func:`~.dense_attention.dense_attention` reads), and equal on every edge to
those of :mod:`.sparse_graphs` (tested).
"""

from __future__ import annotations

import functools

import torch

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
    EdgeType,
    StageGraphs,
)
from .graph_transformer import DenseLayout


class DenseGraphs(StageGraphs):
    """:class:`~.graph.StageGraphs` in the dense layout (module docstring); σ, φ and ψ compiled or not
    (:meth:`~.graph_transformer.HeteroGraphTransformer.compile_dense`)."""

    def local(
        self, scene_positions: torch.Tensor, scene_nodes: torch.Tensor, gripper_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        """Attributes ``enc(p_dst − p_src)`` of every node pair ``(R, n_src, n_dst, E)``, self pairs masked out."""
        frequencies = self.num_frequencies
        gripper_positions = keypoints.expand(len(scene_positions), -1, -1)
        edge_attr = {
            SCENE_TO_SCENE: dense_position_attr(scene_positions, scene_positions, frequencies),
            SCENE_TO_GRIPPER: dense_position_attr(scene_positions, gripper_positions, frequencies),
            GRIPPER_TO_GRIPPER: dense_position_attr(gripper_positions, gripper_positions, frequencies),
        }
        masks = dense_local_masks(scene_positions.shape[1], len(keypoints), scene_positions.device)
        return self.local_network.forward_dense({SCENE: scene_nodes, GRIPPER: gripper_nodes}, edge_attr, masks)[GRIPPER]

    def context(
        self, T_world_ee: torch.Tensor, demo_nodes: torch.Tensor, current_nodes: torch.Tensor, keypoints: torch.Tensor,
    ) -> torch.Tensor:
        """The time edges ``l + 1 → l`` carry ``[enc(t), enc(R k − k)]`` of ``T_l+1,l`` once per source waypoint
        (:func:`dense_transform_attr` on the ``B · N · (L − 1)`` waypoint pairs), the demo → current edges
        ``enc(k_dst − k_src)`` (:func:`dense_keypoint_offset_attr`)."""
        batch, num_demos, demo_length = T_world_ee.shape[:3]
        frequencies = self.num_frequencies
        edge_attr = {
            DEMO_TIME: dense_transform_attr(
                T_world_ee[:, :, 1:].reshape(-1, 1, 4, 4), T_world_ee[:, :, :-1].reshape(-1, 1, 4, 4), keypoints,
                frequencies,
            ),
            DEMO_TO_CURRENT: dense_keypoint_offset_attr(keypoints, num_demos * demo_length, frequencies).expand(
                batch, -1, -1, -1
            ),
        }
        masks = {DEMO_TIME: None, DEMO_TO_CURRENT: None}
        x = {DEMO: demo_nodes, CURRENT: current_nodes}
        return self.context_network.forward_dense(x, edge_attr, masks, dense_context_layouts())[CURRENT]

    def actions(
        self, T_ee_actions: torch.Tensor, current_nodes: torch.Tensor, action_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        """One graph per sample: the current frame (the identity) and the ``T`` action frames, attributes once per
        source frame (:func:`dense_transform_attr`)."""
        batch, horizon = T_ee_actions.shape[:2]
        frequencies = self.num_frequencies
        current_frames = torch.eye(4, dtype=T_ee_actions.dtype, device=T_ee_actions.device).expand(batch, 1, 4, 4)
        edge_attr = {
            CURRENT_TO_ACTION: dense_transform_attr(current_frames, T_ee_actions, keypoints, frequencies),
            ACTION_TO_ACTION: dense_transform_attr(T_ee_actions, T_ee_actions, keypoints, frequencies),
        }
        masks = dense_action_masks(horizon, len(keypoints), T_ee_actions.device)
        x = {CURRENT: current_nodes, ACTION: action_nodes.flatten(1, 2)}
        return self.action_network.forward_dense(x, edge_attr, masks)[ACTION].reshape(action_nodes.shape)


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def dense_local_masks(num_scene: int, num_keypoints: int, device: torch.device) -> dict[EdgeType, torch.Tensor | None]:
    """:func:`~.sparse_graphs.local_graph`'s connectivity in the dense layout: edge type → ``(n_src, n_dst)`` bool
    (``None``: all pairs); no self loops."""
    return {
        SCENE_TO_SCENE: ~torch.eye(num_scene, dtype=torch.bool, device=device),
        SCENE_TO_GRIPPER: None,
        GRIPPER_TO_GRIPPER: ~torch.eye(num_keypoints, dtype=torch.bool, device=device),
    }


@functools.lru_cache(maxsize=32)
@torch.inference_mode(False)
def dense_action_masks(horizon: int, num_keypoints: int, device: torch.device) -> dict[EdgeType, torch.Tensor | None]:
    """:func:`~.sparse_graphs.action_graph`'s connectivity in the dense layout: current → every action node, action
    ``i`` → action ``j ≠ i`` (node ``i · G + k``)."""
    other_frame = ~torch.eye(horizon, dtype=torch.bool, device=device)
    return {
        CURRENT_TO_ACTION: None,
        ACTION_TO_ACTION: other_frame.repeat_interleave(num_keypoints, 0).repeat_interleave(num_keypoints, 1),
    }


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
    """:func:`~.sparse_graphs.context_graph`'s connectivity in the dense layout: every edge type's graphs (no mask
    needed)."""
    return {DEMO_TIME: NextWaypointLayout(), DEMO_TO_CURRENT: AllWaypointsLayout()}


def dense_position_attr(src_positions: torch.Tensor, dst_positions: torch.Tensor, num_frequencies: int) -> torch.Tensor:
    """:func:`~.sparse_graphs.position_attr` of every node pair in the dense layout: ``(G, S, 3)``, ``(G, D, 3)`` →
    ``(G, S, D, ·)``, ``enc(p_dst − p_src)`` at ``[:, src, dst]``, destination-major in memory (the layout
    :func:`~.dense_attention.dense_attention` reads)."""
    offsets = dst_positions[:, :, None, :] - src_positions[:, None, :, :]  # (G, D, S, 3)
    return sinusoidal_encoding(offsets, num_frequencies).transpose(1, 2)


@full_precision()
def dense_transform_attr(
    src_frames: torch.Tensor, dst_frames: torch.Tensor, keypoints: torch.Tensor, num_frequencies: int
) -> torch.Tensor:
    """:func:`~.sparse_graphs.transform_attr` of every keypoint pair between frames, in the dense layout, once per
    source frame: the attribute does not depend on the source keypoint.

    Args:
        src_frames: ``(B, F_src, 4, 4)`` and ``dst_frames``: ``(B, F_dst, 4, 4)``, poses in a common frame per row.
        keypoints: ``(G, 3)`` gripper keypoints.

    Returns:
        ``(B, F_src, F_dst · G, 2 E)``: the attribute of the edges from every keypoint of source frame ``i`` to
        keypoint ``k_d`` of destination frame ``j`` at ``[:, i, j · G + k_d]``, as
        :func:`~.sparse_graphs.transform_attr` gives it on each of those edges; shared by the ``G`` source nodes of
        frame ``i`` (:func:`~.dense_attention.dense_attention`), destination-major in memory (the layout it reads).
    """
    batch, num_src, num_dst, num_keypoints = src_frames.shape[0], src_frames.shape[1], dst_frames.shape[1], len(keypoints)
    R_src_t = src_frames[:, None, :, :3, :3].transpose(-1, -2)  # (B, 1, F_src, 3, 3)
    R = R_src_t @ dst_frames[:, :, None, :3, :3]  # (B, F_dst, F_src, 3, 3)
    t = (R_src_t @ (dst_frames[:, :, None, :3, 3] - src_frames[:, None, :, :3, 3])[..., None]).squeeze(-1)
    displacement = (keypoints @ R.transpose(-1, -2) - keypoints).transpose(2, 3)  # (B, F_dst, G, F_src, 3): R k − k
    translation = sinusoidal_encoding(t, num_frequencies)[:, :, None].expand(-1, -1, num_keypoints, -1, -1)
    attr = torch.cat([translation, sinusoidal_encoding(displacement, num_frequencies)], dim=-1)
    return attr.view(batch, num_dst * num_keypoints, num_src, attr.shape[-1]).transpose(1, 2)


def dense_keypoint_offset_attr(keypoints: torch.Tensor, num_frames: int, num_frequencies: int) -> torch.Tensor:
    """:func:`~.sparse_graphs.keypoint_offset_attr` of φ's demo → current edges in the dense layout of
    :class:`AllWaypointsLayout`: keypoints ``(G, 3)`` → ``(1, F · G, G, ·)``, ``enc(k_dst − k_src)`` at
    ``[0, f · G + k_src, k_dst]`` for each of the ``F = N · L`` demo frames, destination-major in memory."""
    offsets = keypoints[None, :, None, :] - keypoints[None, None, :, :]  # (1, G_dst, G_src, 3)
    return sinusoidal_encoding(offsets, num_frequencies).repeat(1, 1, num_frames, 1).transpose(1, 2)
