"""A control step's context from words: the language head's bottleneck in place of φ's on demonstrations, in the
:class:`~..model.instant_policy_network.InstantPolicyContext` that the trained network's ψ samples actions from
(:meth:`~..model.instant_policy_network.InstantPolicyNetwork.sample_actions`), exactly as after
:meth:`~..model.instant_policy_network.InstantPolicyNetwork.encode_context` with demonstrations."""

from __future__ import annotations

import torch

from ..geometry.rigid_torch import invert_rigid, transform_points
from ..model.instant_policy_network import InstantPolicyContext, InstantPolicyNetwork
from .language_head import LanguageHead


@torch.no_grad()
def language_context(
    network: InstantPolicyNetwork, head: LanguageHead, text: torch.Tensor, points_world: torch.Tensor,
    T_world_ee: torch.Tensor, gripper: torch.Tensor,
) -> InstantPolicyContext:
    """The context of one control step of a task said in words.

    Args:
        network: the trained network the head was made for (frozen here).
        head: the language head.
        text: ``(B, E)`` the sentence vectors (:meth:`~.text_encoder.TextEncoder.encode`).
        points_world: ``(B, P, 3)`` the live cloud in the world frame.
        T_world_ee: ``(B, 4, 4)`` the current EE pose in the world frame.
        gripper: ``(B,)`` the current gripper state, 1 open, 0 closed.

    Returns:
        The context with the predicted bottleneck ``(B, G, H)``, the live cloud in the EE frame ``(B, P, 3)`` and its
        scene nodes in the EE frame ``(B, M, 3)``, ``(B, M, D)``.
    """
    batch = len(points_world)
    network._check_cloud("points_world", points_world, (batch,))
    network._check_tensor("T_world_ee", T_world_ee, (batch, 4, 4))
    network._check_tensor("gripper", gripper, (batch,))
    points_ee = transform_points(invert_rigid(T_world_ee), points_world)
    scene_positions, scene_features = network.encode_clouds(points_ee)
    bottleneck = head.bottleneck(network, scene_positions, scene_features, gripper, text)
    return InstantPolicyContext(current_gripper_features=bottleneck, points_ee=points_ee,
                                scene_positions_ee=scene_positions, scene_features=scene_features)
