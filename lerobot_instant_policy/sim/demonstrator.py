"""Scripted Cartesian demonstrations: waypoints in the world frame, interpolated into bounded env steps."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..contract import vectors_from_poses
from ..geometry.se3 import look_rotation, make_pose, pose_distance, slerp_rotations

MAX_DEMO_TRANSLATION = 0.01
MAX_DEMO_ROTATION = np.radians(3.0)
GRIPPER_HOLD_STEPS = 4
DOWN = np.array([0.0, 0.0, -1.0])


@dataclass
class ScriptedWaypoint:
    """An EE target ``T_world_ee (4, 4)`` and the gripper command to hold there (``True`` open).

    ``hold_steps``: extra steps spent at the waypoint; ``None`` gives ``GRIPPER_HOLD_STEPS`` when the gripper
    command changes here (time to close or open the fingers) and 0 otherwise.
    """

    T_world_ee: np.ndarray
    gripper_open: bool
    hold_steps: int | None = None


def top_down_pose(position, yaw: float = np.pi / 2) -> np.ndarray:
    """``T_world_ee (4, 4)`` at ``position (3,)`` approaching straight down; ``yaw`` turns the finger axis.

    At ``yaw = π/2`` (the robot's home orientation) the fingers open along the world y axis.
    """
    return make_pose(np.asarray(position, dtype=np.float64), look_rotation(DOWN, yaw))


def approach_pose(position, approach: np.ndarray, yaw: float = np.pi / 2) -> np.ndarray:
    """``T_world_ee (4, 4)`` at ``position (3,)`` whose z axis is ``approach (3,)`` (see ``look_rotation``)."""
    return make_pose(np.asarray(position, dtype=np.float64), look_rotation(np.asarray(approach, dtype=float), yaw))


def grasp_yaw(axis_yaw: float, symmetry: float, reference: float = np.pi / 2) -> float:
    """The ``top_down_pose`` yaw whose finger axis lies along world direction ``axis_yaw`` (rad, modulo
    ``symmetry``), choosing among the equivalent ones the closest to ``reference`` (least wrist rotation).

    A top-down EE at yaw ψ has its finger axis along world direction −ψ.
    """
    k = np.round((reference + axis_yaw) / symmetry)
    return float(-axis_yaw + k * symmetry)


def interpolate_waypoints(
    T_world_start: np.ndarray,
    gripper_open_start: bool,
    waypoints: list[ScriptedWaypoint],
    max_translation: float = MAX_DEMO_TRANSLATION,
    max_rotation: float = MAX_DEMO_ROTATION,
) -> np.ndarray:
    """Actions ``(S, 8)`` (EE xyz, quat xyzw, gripper 1 open / 0 close) that visit ``waypoints`` in order.

    Consecutive targets are at most ``max_translation`` (m) and ``max_rotation`` (rad) apart (linear
    translation, slerp rotation). The gripper command of a waypoint starts on the step that reaches it.
    """
    actions = []
    T_previous, gripper = T_world_start, bool(gripper_open_start)
    for waypoint in waypoints:
        translation, rotation = pose_distance(T_previous, waypoint.T_world_ee)
        steps = max(1, int(np.ceil(max(translation / max_translation, rotation / max_rotation) - 1e-9)))
        fractions = np.arange(1, steps + 1) / steps
        rotations = slerp_rotations(T_previous[:3, :3], waypoint.T_world_ee[:3, :3], fractions)
        for index, fraction in enumerate(fractions):
            position = (1 - fraction) * T_previous[:3, 3] + fraction * waypoint.T_world_ee[:3, 3]
            command = waypoint.gripper_open if index == steps - 1 else gripper
            actions.append(vectors_from_poses(make_pose(position, rotations[index]), command))
        hold = waypoint.hold_steps
        if hold is None:
            hold = GRIPPER_HOLD_STEPS if waypoint.gripper_open != gripper else 0
        actions.extend([actions[-1]] * hold)
        T_previous, gripper = waypoint.T_world_ee, waypoint.gripper_open
    return np.asarray(actions, dtype=np.float64).reshape(-1, 8)
