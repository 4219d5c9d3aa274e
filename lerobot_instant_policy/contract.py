"""The data contract (docs/design.md §4): the LeRobot feature keys, their shapes and names, and the one codec of the
8-vector.

Every frame has ``observation.pointcloud (P, 3)`` (segmented object points, world frame, metres),
``observation.state (8,)`` (the EE pose in the world frame and the gripper state) and ``action (8,)`` (the commanded
EE pose for the next step and the gripper command, same layout). The 8-vector is the position xyz (m), the
orientation quaternion xyzw (written with ``w ≥ 0``), then the gripper (1 open, 0 closed).

The codec turns vectors ``(..., 8)`` into ``T_world_ee (..., 4, 4)`` (maps points in the EE frame to the world frame)
and the gripper ``(...)``, and back: :func:`poses_from_vectors` / :func:`vectors_from_poses` in numpy (float64),
:func:`poses_from_vectors_torch` / :func:`vectors_from_poses_torch` in torch (the input's dtype and device).
"""

from __future__ import annotations

import numpy as np
import roma
import torch
from scipy.spatial.transform import Rotation

from .geometry.rigid_torch import make_rigid

POINTCLOUD_KEY = "observation.pointcloud"
STATE_KEY = "observation.state"
ACTION_KEY = "action"

# A training batch that carries its own context (the pseudo-task stream) instead of drawing it from a dataset: per row
# N demonstrations reduced to L waypoints, ``(B, N, L, P, 3)`` world-frame clouds, ``(B, N, L, 4, 4)`` EE poses,
# ``(B, N, L)`` commanded gripper states, and ``(B,)`` int64 ids (rows with one id share one context). Under
# ``observation.`` so that LeRobot's processors pass them on.
CONTEXT_POINTCLOUD_KEY = "observation.context.pointcloud"
CONTEXT_T_WORLD_EE_KEY = "observation.context.T_world_ee"
CONTEXT_GRIPPER_OPEN_KEY = "observation.context.gripper_open"
CONTEXT_ID_KEY = "observation.context.id"
CONTEXT_KEYS = (CONTEXT_POINTCLOUD_KEY, CONTEXT_T_WORLD_EE_KEY, CONTEXT_GRIPPER_OPEN_KEY, CONTEXT_ID_KEY)

# A training batch whose clouds the frozen geometry encoder has already read (the encoded task pool): per row the
# live frame's M scene nodes in its own EE frame, positions ``(B, M, 3)`` and features ``(B, M, D)``, in place of its
# cloud, and the context's waypoints likewise, ``(B, N, L, M, 3)`` and ``(B, N, L, M, D)``, in place of theirs,
# beside the context's poses, gripper states and ids above.
SCENE_POSITIONS_KEY = "observation.scene_positions"
SCENE_FEATURES_KEY = "observation.scene_features"
CONTEXT_SCENE_POSITIONS_KEY = "observation.context.scene_positions"
CONTEXT_SCENE_FEATURES_KEY = "observation.context.scene_features"
ENCODED_KEYS = (SCENE_POSITIONS_KEY, SCENE_FEATURES_KEY, CONTEXT_SCENE_POSITIONS_KEY, CONTEXT_SCENE_FEATURES_KEY,
                CONTEXT_T_WORLD_EE_KEY, CONTEXT_GRIPPER_OPEN_KEY, CONTEXT_ID_KEY)

# Training to refine (``InstantPolicyConfig.refine_fraction``): per row the replay prior of its ``T`` actions, what the
# context's replay plan commands there, ``(B, T, 8)`` absolute world-frame EE targets in the 8-vector layout.
REPLAY_PRIOR_KEY = "observation.replay_prior"
# and per row whether training may start from it ``(B,)`` bool: False for a wrong prior the stream leaves out
# (``StreamConfig.wrong_prior_keep``), whose row then keeps the paper's loss.
REPLAY_PRIOR_KEPT_KEY = "observation.replay_prior_kept"

NUM_POINTS = 2048
POINTCLOUD_NAMES = ["point", "xyz"]
POSE_GRIPPER_NAMES = ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open"]
POSE_GRIPPER_SHAPE = (len(POSE_GRIPPER_NAMES),)

_POSITION = slice(0, 3)
_QUATERNION = slice(3, 7)
_GRIPPER = 7
_MIN_QUATERNION_NORM = 1e-6
_ZERO_QUATERNION = "an EE pose has a zero quaternion (entries 3…6, xyzw); poses must hold unit quaternions"


def poses_from_vectors(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``vectors (..., 8)`` → ``T_world_ee (..., 4, 4)`` and ``gripper_open (...)``, float64; the quaternion is
    normalised. A zero quaternion raises ``ValueError``."""
    vectors = _checked_vectors(np.asarray(vectors, dtype=np.float64))
    quaternion = vectors[..., _QUATERNION]
    if bool((np.linalg.norm(quaternion, axis=-1) < _MIN_QUATERNION_NORM).any()):
        raise ValueError(_ZERO_QUATERNION)
    batch = vectors.shape[:-1]
    T_world_ee = np.zeros((*batch, 4, 4))
    T_world_ee[..., :3, :3] = Rotation.from_quat(quaternion.reshape(-1, 4)).as_matrix().reshape(*batch, 3, 3)
    T_world_ee[..., :3, 3] = vectors[..., _POSITION]
    T_world_ee[..., 3, 3] = 1.0
    return T_world_ee, vectors[..., _GRIPPER].copy()


def vectors_from_poses(T_world_ee: np.ndarray, gripper_open: np.ndarray | float | bool) -> np.ndarray:
    """``T_world_ee (..., 4, 4)`` and ``gripper_open (...)`` (a bool for one pose too) → ``(..., 8)`` float64: xyz,
    quaternion xyzw with ``w ≥ 0``, gripper."""
    T_world_ee = np.asarray(T_world_ee, dtype=np.float64)
    batch = T_world_ee.shape[:-2]
    quaternion = Rotation.from_matrix(T_world_ee[..., :3, :3].reshape(-1, 3, 3)).as_quat().reshape(*batch, 4)
    quaternion = np.where(quaternion[..., 3:4] < 0, -quaternion, quaternion)
    gripper = np.broadcast_to(np.asarray(gripper_open, dtype=np.float64), batch)
    return np.concatenate([T_world_ee[..., :3, 3], quaternion, gripper[..., None]], axis=-1)


def poses_from_vectors_torch(vectors: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``vectors (..., 8)`` → ``T_world_ee (..., 4, 4)`` and ``gripper_open (...)`` in the vectors' dtype and device;
    the quaternion is normalised. A zero quaternion raises ``ValueError``."""
    _checked_vectors(vectors)
    quaternion = vectors[..., _QUATERNION]
    norm = quaternion.norm(dim=-1, keepdim=True)
    if bool((norm < _MIN_QUATERNION_NORM).any()):
        raise ValueError(_ZERO_QUATERNION)
    return make_rigid(roma.unitquat_to_rotmat(quaternion / norm), vectors[..., _POSITION]), vectors[..., _GRIPPER]


def vectors_from_poses_torch(T_world_ee: torch.Tensor, gripper_open: torch.Tensor) -> torch.Tensor:
    """``T_world_ee (..., 4, 4)`` and ``gripper_open (...)`` → ``(..., 8)`` in the poses' dtype: xyz, quaternion xyzw
    with ``w ≥ 0``, gripper."""
    quaternion = roma.rotmat_to_unitquat(T_world_ee[..., :3, :3])
    quaternion = torch.where(quaternion[..., 3:4] < 0, -quaternion, quaternion)
    return torch.cat([T_world_ee[..., :3, 3], quaternion, gripper_open[..., None].to(T_world_ee.dtype)], dim=-1)


def checked_observation(batch: dict, num_points: int,
                        cloud_required: bool = True) -> tuple[torch.Tensor | None, torch.Tensor]:
    """``points_world (B, P, 3)`` and ``state (B, 8)`` of a policy batch, float32 and checked against the contract
    with ``P = num_points``: ``KeyError`` for a missing key, ``ValueError`` naming a wrong shape or a non-finite value.
    Without ``cloud_required`` a batch without ``observation.pointcloud`` gives ``points_world`` None."""
    required = (POINTCLOUD_KEY, STATE_KEY) if cloud_required or POINTCLOUD_KEY in batch else (STATE_KEY,)
    for key in required:
        if key not in batch:
            raise KeyError(f"instant_policy needs {key!r} in the batch, got keys {sorted(batch)}")
    state = batch[STATE_KEY]
    if state.ndim != 2 or state.shape[1] != 8:
        raise ValueError(f"{STATE_KEY!r} must have shape (B, 8), got {tuple(state.shape)}")
    if not torch.isfinite(state).all():
        raise ValueError(f"{STATE_KEY!r} contains NaN or infinite values")
    if POINTCLOUD_KEY not in required:
        return None, state.float()
    points = batch[POINTCLOUD_KEY]
    expected = (len(state), num_points, 3)
    if tuple(points.shape) != expected:
        raise ValueError(
            f"point clouds of the wrong size: {POINTCLOUD_KEY!r} must have shape (B, P, 3) = {expected}, got "
            f"{tuple(points.shape)}; resample each cloud to {num_points} points"
        )
    if not torch.isfinite(points).all():
        raise ValueError(f"{POINTCLOUD_KEY!r} contains NaN or infinite values")
    return points.float(), state.float()


def _checked_vectors(vectors):
    """``vectors`` (numpy or torch), after checking that their last axis is the 8-vector."""
    if vectors.ndim < 1 or vectors.shape[-1] != POSE_GRIPPER_SHAPE[0]:
        raise ValueError(
            f"EE pose vectors must have shape (..., {POSE_GRIPPER_SHAPE[0]}) (xyz, quaternion xyzw, gripper), "
            f"got {tuple(vectors.shape)}"
        )
    return vectors
