"""The data contract's EE pose and EE-target actions on MetaWorld's Sawyer, and MetaWorld's 4-D action.

The EE frame (docs/deployment.md §2): origin at MetaWorld's ``tcp_center`` (midway between the fingertip sites
``rightEndEffector`` and ``leftEndEffector``, the point MetaWorld's own rewards use), z the approach axis (out of
the hand, down for MetaWorld's fixed top-down hand), y the axis along which the fingers open. MetaWorld's ``hand``
body has x as its approach axis and y along the fingers, so ``R_world_ee = R_world_hand · R_hand_ee`` with
``R_hand_ee`` a +90° turn about y.

MetaWorld's action ``(4,)`` in ``[-1, 1]``: a mocap displacement ``action[:3] · action_scale`` (m; 0.01 in every
v3 task) and the finger actuators' target (+1 closes, −1 opens). An absolute target ``(8,)`` of the contract maps
to it as

    action[:3] = clip((target_xyz − ee_xyz) / action_scale, −1, 1),   action[3] = −1 if gripper_open ≥ 0.5 else +1

so a target within one ``action_scale`` of the EE on every axis is reached in one step (the hand follows the mocap
through a weld; contacts may hold it back), and a further one is approached at MetaWorld's top speed. MetaWorld's
hand cannot turn (its mocap orientation is fixed at reset), so the target's quaternion is not used.
:func:`ee_target` is the inverse for a MetaWorld action (its scripted experts'): it returns the target that maps
back to that action, exactly for actions in ``[-1, 1]`` with a gripper of ±1.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ...contract import POSE_GRIPPER_SHAPE, vectors_from_poses

R_HAND_EE = Rotation.from_euler("y", 90.0, degrees=True).as_matrix()
GRIPPER_CLOSE = 1.0  # MetaWorld's finger command that closes; −1 opens


def metaworld_action(target: np.ndarray, ee_position: np.ndarray, action_scale: float) -> np.ndarray:
    """``target (8,)`` (absolute EE target, world frame, gripper 1 open / 0 close) and ``ee_position (3,)`` (m) →
    MetaWorld's action ``(4,)`` float32 (module docstring). A target of the wrong shape or with NaN/inf raises
    ``ValueError``."""
    target = np.asarray(target, dtype=np.float64)
    if target.shape != POSE_GRIPPER_SHAPE or not np.all(np.isfinite(target)):
        raise ValueError(f"a MetaWorld EE target must be a finite (8,) vector (xyz, quaternion xyzw, gripper), got "
                         f"shape {target.shape}")
    delta = np.clip((target[:3] - np.asarray(ee_position, dtype=np.float64)) / action_scale, -1.0, 1.0)
    gripper = -GRIPPER_CLOSE if target[7] >= 0.5 else GRIPPER_CLOSE
    return np.append(delta, gripper).astype(np.float32)


def ee_target(action: np.ndarray, ee_state: np.ndarray, action_scale: float) -> np.ndarray:
    """MetaWorld's ``action (4,)`` → the absolute target ``(8,)`` float32 that :func:`metaworld_action` maps back
    to it, from ``ee_state (8,)`` (the current EE pose and gripper): position ``ee_xyz + clip(action[:3]) ·
    action_scale``, the current orientation, gripper closed (0) for a command above 0, open (1) otherwise (the
    experts command 0 for "not gripping" and 0.1…1 for grips of several strengths, all mapped to +1)."""
    action = np.asarray(action, dtype=np.float64)
    target = np.array(ee_state, dtype=np.float64)
    target[:3] += np.clip(action[:3], -1.0, 1.0) * action_scale
    target[7] = 0.0 if action[3] > 0 else 1.0
    return target.astype(np.float32)


def ee_state(hand_rotation: np.ndarray, tcp_position: np.ndarray, gripper_open: bool) -> np.ndarray:
    """The contract's ``observation.state (8,)`` float32 from the hand body's ``R_world_hand (3, 3)``, MetaWorld's
    ``tcp_center (3,)`` (m) and the gripper state (module docstring)."""
    T_world_ee = np.eye(4)
    T_world_ee[:3, :3] = np.asarray(hand_rotation).reshape(3, 3) @ R_HAND_EE
    T_world_ee[:3, 3] = tcp_position
    return vectors_from_poses(T_world_ee, float(gripper_open)).astype(np.float32)
