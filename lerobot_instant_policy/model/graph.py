"""The heterogeneous graph of Instant Policy (paper §3.1, docs/design.md §5): node and edge types, attribute widths,
and :class:`StageGraphs`, the interface through which the network runs σ, φ and ψ on it.

A *local graph* is one time step seen from its own end-effector frame: ``M`` scene nodes (geometry-encoder
centroids of the cloud expressed in that frame) and ``G = 6`` gripper nodes at fixed keypoints of the gripper.
Per sample there are ``N · L`` demonstration local graphs, one current local graph and ``T`` action local graphs.
The networks see three subgraphs:

- local (σ): node types ``scene``, ``gripper``; edges scene→scene, scene→gripper and gripper→gripper inside every
  local graph (no self loops);
- context (φ): node types ``demo`` and ``current`` (the gripper nodes of the demonstration and current local
  graphs); edges demo waypoint ``l+1`` → ``l`` (every keypoint pair) and every demo gripper node of a sample →
  every current gripper node of that sample;
- action (ψ): node types ``current`` and ``action``; edges current → every action gripper node, and action ``i`` →
  action ``j`` for ``i ≠ j`` (every keypoint pair).

Edge attributes: inside a local graph, ``enc(p_dst − p_src)`` (sin/cos at ``2⁰π … 2⁹π`` plus the raw vector).
Between frames of one world (demo time edges, current → action, action → action), the attribute describes the
relative transform ``T_src,dst = T_src⁻¹ T_dst = (R, t)``: ``[enc(t), enc(R k − k)]`` with ``k`` the destination's
keypoint, i.e. the translation and the displacement that the rotation gives that keypoint. Demonstrations and the
current observation live in different worlds, so demo → current edges carry ``enc(k_dst − k_src)`` in the gripper
frame. Every attribute is relative, so moving a whole world rigidly changes none of them.

Two implementations of :class:`StageGraphs` give the same outputs and gradients with the same weights
(``tests/model/test_dense_attention.py``): :class:`~.sparse_graphs.SparseGraphs` builds these graphs as torch_geometric
``HeteroData`` and runs PyG's layers on their edge lists (the reference); :class:`~.dense_graphs.DenseGraphs` lays
every edge type out as batches of complete bipartite graphs and runs the same layers densely (the network's).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING

import torch

from .encodings import encoding_dim

if TYPE_CHECKING:
    from .graph_transformer import HeteroGraphTransformer

SCENE, GRIPPER, DEMO, CURRENT, ACTION = "scene", "gripper", "demo", "current", "action"
SCENE_TO_SCENE = (SCENE, "local", SCENE)
SCENE_TO_GRIPPER = (SCENE, "local", GRIPPER)
GRIPPER_TO_GRIPPER = (GRIPPER, "local", GRIPPER)
DEMO_TIME = (DEMO, "time", DEMO)
DEMO_TO_CURRENT = (DEMO, "context", CURRENT)
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


def context_edge_dims(num_frequencies: int) -> dict[EdgeType, int]:
    return {DEMO_TIME: transform_dim(num_frequencies), DEMO_TO_CURRENT: position_dim(num_frequencies)}


def action_edge_dims(num_frequencies: int) -> dict[EdgeType, int]:
    return {CURRENT_TO_ACTION: transform_dim(num_frequencies), ACTION_TO_ACTION: transform_dim(num_frequencies)}


class StageGraphs(ABC):
    """σ, φ and ψ on their graphs, given each stage's node tensors: the network's three
    :class:`~.graph_transformer.HeteroGraphTransformer` (their weights) run on the connectivity and edge attributes
    of the module docstring, built here from the node positions and frames.

    Args:
        local_network: σ, context_network: φ, action_network: ψ: the network's graph transformers (the layouts hold
            them, the network owns them, so the state dict's names do not depend on the layout).
        num_frequencies: the sinusoidal encoding's frequencies in every edge attribute.

    Sizes: ``R`` local graphs, ``B`` samples, ``N`` demonstrations of ``L`` waypoints, ``T`` actions, ``M`` scene
    nodes and ``G`` gripper nodes per local graph, ``H`` hidden features. ``keypoints (G, 3)`` are the gripper
    keypoints in the EE frame: the gripper nodes' positions in every local graph, in the dtype and on the device of
    the positions and frames they meet.
    """

    def __init__(
        self, local_network: HeteroGraphTransformer, context_network: HeteroGraphTransformer,
        action_network: HeteroGraphTransformer, num_frequencies: int,
    ):
        self.local_network, self.context_network, self.action_network = local_network, context_network, action_network
        self.num_frequencies = num_frequencies

    @abstractmethod
    def local(
        self, scene_positions: torch.Tensor, scene_nodes: torch.Tensor, gripper_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        """σ on ``R`` local graphs.

        Args:
            scene_positions: ``(R, M, 3)`` the scene nodes of each graph in that graph's EE frame.
            scene_nodes: ``(R, M, H)`` their features (the network's scene projection); may be expanded along ``R``
                (one scene seen from ``T`` action frames).
            gripper_nodes: ``(R, G, H)`` the gripper nodes' features.
            keypoints: ``(G, 3)``.

        Returns:
            ``(R, G, H)`` the gripper nodes after σ.
        """

    @abstractmethod
    def context(
        self, T_world_ee: torch.Tensor, demo_nodes: torch.Tensor, current_nodes: torch.Tensor, keypoints: torch.Tensor,
    ) -> torch.Tensor:
        """φ: the demonstrations' gripper nodes → the current gripper nodes.

        Args:
            T_world_ee: ``(B, N, L, 4, 4)`` the demo waypoints' EE poses in their demonstration's world frame.
            demo_nodes: ``(B, N, L, G, H)`` the demo gripper nodes after σ.
            current_nodes: ``(B, G, H)`` the current gripper nodes after σ.
            keypoints: ``(G, 3)``.

        Returns:
            ``(B, G, H)`` the current gripper nodes after φ.
        """

    @abstractmethod
    def actions(
        self, T_ee_actions: torch.Tensor, current_nodes: torch.Tensor, action_nodes: torch.Tensor,
        keypoints: torch.Tensor,
    ) -> torch.Tensor:
        """ψ: the current gripper nodes → the action gripper nodes.

        Args:
            T_ee_actions: ``(B, T, 4, 4)`` the action frames in the current EE frame.
            current_nodes: ``(B, G, H)`` the current gripper nodes after φ.
            action_nodes: ``(B, T, G, H)`` the action gripper nodes (after σ where actions have local graphs).
            keypoints: ``(G, 3)``.

        Returns:
            ``(B, T, G, H)`` the action gripper nodes after ψ.
        """
