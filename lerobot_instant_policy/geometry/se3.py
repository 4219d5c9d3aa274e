"""Rigid transforms in numpy.

Poses are ``(4, 4)`` float64 homogeneous matrices named ``T_<to>_<from>``: ``T_world_ee`` maps points
expressed in the EE frame to the world frame. Quaternions follow the data contract: ``xyzw``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def make_pose(position: np.ndarray, rotation: Rotation | np.ndarray | None = None) -> np.ndarray:
    """Build a ``(4, 4)`` pose from a position ``(3,)`` and a rotation (``Rotation`` or ``(3, 3)``)."""
    pose = np.eye(4)
    pose[:3, 3] = position
    if rotation is not None:
        pose[:3, :3] = rotation.as_matrix() if isinstance(rotation, Rotation) else rotation
    return pose


def pose_from_pos_quat(position: np.ndarray, quat_xyzw: np.ndarray) -> np.ndarray:
    """``(3,)`` position and ``(4,)`` xyzw quaternion → ``(4, 4)`` pose."""
    return make_pose(np.asarray(position, dtype=np.float64), Rotation.from_quat(quat_xyzw))


def pose_to_pos_quat(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(4, 4)`` pose → ``(3,)`` position, ``(4,)`` xyzw quaternion with non-negative w."""
    quat = Rotation.from_matrix(pose[:3, :3]).as_quat()
    if quat[3] < 0:
        quat = -quat
    return pose[:3, 3].copy(), quat


def invert(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid ``(..., 4, 4)`` pose."""
    rot_t = np.swapaxes(pose[..., :3, :3], -1, -2)
    inverse = np.zeros_like(pose)
    inverse[..., :3, :3] = rot_t
    inverse[..., :3, 3] = -(rot_t @ pose[..., :3, 3:4])[..., 0]
    inverse[..., 3, 3] = 1.0
    return inverse


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``pose (4, 4)`` to ``points (P, 3)``."""
    return points @ pose[:3, :3].T + pose[:3, 3]


def rotation_angle(rot_a: np.ndarray, rot_b: np.ndarray) -> np.ndarray:
    """Geodesic angle in radians between rotation matrices ``(..., 3, 3)`` (atan2 form: accurate near 0 and π)."""
    relative = np.swapaxes(rot_a, -1, -2) @ rot_b
    cos = np.trace(relative, axis1=-2, axis2=-1) - 1.0
    skew = np.stack(
        [relative[..., 2, 1] - relative[..., 1, 2], relative[..., 0, 2] - relative[..., 2, 0], relative[..., 1, 0] - relative[..., 0, 1]],
        axis=-1,
    )
    return np.arctan2(np.linalg.norm(skew, axis=-1), cos)


def pose_distance(pose_a: np.ndarray, pose_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and rotation angle (rad) between poses ``(..., 4, 4)``."""
    translation = np.linalg.norm(pose_a[..., :3, 3] - pose_b[..., :3, 3], axis=-1)
    return translation, rotation_angle(pose_a[..., :3, :3], pose_b[..., :3, :3])


def slerp_rotations(rot_a: np.ndarray, rot_b: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Spherical interpolation between two ``(3, 3)`` rotations at ``fractions (F,)`` → ``(F, 3, 3)``."""
    keys = Rotation.from_matrix(np.stack([rot_a, rot_b]))
    return Slerp([0.0, 1.0], keys)(np.clip(fractions, 0.0, 1.0)).as_matrix()


def look_rotation(approach: np.ndarray, yaw: float) -> np.ndarray:
    """Rotation whose z-axis is ``approach (3,)`` and whose x/y axes are turned by ``yaw`` about it.

    Used for gripper poses: the EE z-axis is the approach direction, y the finger-opening axis.
    """
    z_axis = approach / np.linalg.norm(approach)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z_axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(helper, z_axis)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    base = np.stack([x_axis, y_axis, z_axis], axis=1)
    return base @ Rotation.from_euler("z", yaw).as_matrix()
