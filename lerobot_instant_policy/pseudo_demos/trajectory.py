"""Gripper motion between waypoints: interpolation, uniform resampling and augmentation.

All poses are ``(4, 4)`` world-frame ``T_world_ee``. A trajectory is a list of ``Step``: the observed
EE pose and gripper state of a frame, and the action commanded from it (next pose + gripper).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..geometry.se3 import make_pose, pose_distance, slerp_rotations

MAX_STEP_TRANSLATION = 0.01
MAX_STEP_ROTATION = np.deg2rad(3.0)
_DENSE_SAMPLES = 64


@dataclass
class Step:
    """One frame: observed ``T_world_ee (4, 4)``, observed ``gripper_open``, and the commanded action.

    ``gripper_fault`` marks a frame whose observed gripper state is wrong (see ``add_gripper_faults``).
    """

    T_world_ee: np.ndarray
    gripper_open: bool
    action_T_world_ee: np.ndarray
    action_gripper_open: bool
    gripper_fault: bool = False


def interpolate_linear(T_start: np.ndarray, T_end: np.ndarray, count: int = _DENSE_SAMPLES) -> np.ndarray:
    """Straight line in position, slerp in rotation → ``(count, 4, 4)``."""
    fractions = np.linspace(0.0, 1.0, count)
    positions = T_start[:3, 3] + fractions[:, None] * (T_end[:3, 3] - T_start[:3, 3])
    return _stack(positions, slerp_rotations(T_start[:3, :3], T_end[:3, :3], fractions))


def interpolate_cubic(
    T_start: np.ndarray, T_end: np.ndarray, control_offsets: np.ndarray, count: int = _DENSE_SAMPLES
) -> np.ndarray:
    """Cubic Bézier in position with controls ``start + offsets[0]`` and ``end + offsets[1]`` (world, m)."""
    fractions = np.linspace(0.0, 1.0, count)[:, None]
    p0, p3 = T_start[:3, 3], T_end[:3, 3]
    p1, p2 = p0 + control_offsets[0], p3 + control_offsets[1]
    positions = (
        (1 - fractions) ** 3 * p0
        + 3 * (1 - fractions) ** 2 * fractions * p1
        + 3 * (1 - fractions) * fractions**2 * p2
        + fractions**3 * p3
    )
    return _stack(positions, slerp_rotations(T_start[:3, :3], T_end[:3, :3], fractions[:, 0]))


def interpolate_spherical(
    T_start: np.ndarray, T_end: np.ndarray, center: np.ndarray, count: int = _DENSE_SAMPLES
) -> np.ndarray:
    """Arc about ``center (3,)``: slerp of the direction, linear radius; slerp in rotation.

    With the centre on a hinge axis and both ends perpendicular to it, this is a rotation about the hinge.
    """
    fractions = np.linspace(0.0, 1.0, count)
    start, end = T_start[:3, 3] - center, T_end[:3, 3] - center
    radius_start, radius_end = np.linalg.norm(start), np.linalg.norm(end)
    if radius_start < 1e-6 or radius_end < 1e-6:
        return interpolate_linear(T_start, T_end, count)
    direction_start, direction_end = start / radius_start, end / radius_end
    turn = Rotation.align_vectors(direction_end[None], direction_start[None])[0]
    if np.linalg.norm(np.cross(direction_start, direction_end)) < 1e-6 and direction_start @ direction_end < 0:
        return interpolate_linear(T_start, T_end, count)
    arc = Slerp([0.0, 1.0], Rotation.concatenate([Rotation.identity(), turn]))(fractions)
    radii = radius_start + fractions * (radius_end - radius_start)
    positions = center + arc.apply(direction_start) * radii[:, None]
    return _stack(positions, slerp_rotations(T_start[:3, :3], T_end[:3, :3], fractions))


def resample_uniform(
    dense: np.ndarray,
    max_translation: float = MAX_STEP_TRANSLATION,
    max_rotation: float = MAX_STEP_ROTATION,
) -> np.ndarray:
    """Resample a dense path ``(S, 4, 4)`` to equal steps of at most ``max_translation`` and ``max_rotation``.

    The path is measured with ``max(Δt / max_translation, Δθ / max_rotation)`` per dense step; outputs lie at
    equal fractions of that length, so (triangle inequality) no output step exceeds either bound.
    Returns ``(F, 4, 4)`` including both ends; ``F >= 2`` unless the path has zero length (then ``F == 1``).
    """
    translation, rotation = pose_distance(dense[:-1], dense[1:])
    step_cost = np.maximum(translation / max_translation, rotation / max_rotation)
    cumulative = np.concatenate([[0.0], np.cumsum(step_cost)])
    total = cumulative[-1]
    if total < 1e-9:
        return dense[:1].copy()
    count = int(np.ceil(total - 1e-9))
    targets = np.linspace(0.0, total, count + 1)
    segment = np.clip(np.searchsorted(cumulative, targets, side="right") - 1, 0, len(dense) - 2)
    span = np.maximum(step_cost[segment], 1e-12)
    fraction = np.clip((targets - cumulative[segment]) / span, 0.0, 1.0)
    positions = dense[segment, :3, 3] + fraction[:, None] * (dense[segment + 1, :3, 3] - dense[segment, :3, 3])
    start = Rotation.from_matrix(dense[segment, :3, :3])
    delta = start.inv() * Rotation.from_matrix(dense[segment + 1, :3, :3])
    rotations = start * Rotation.from_rotvec(delta.as_rotvec() * fraction[:, None])
    return _stack(positions, rotations.as_matrix())


def steps_from_states(poses: list[np.ndarray], grippers: list[bool]) -> list[Step]:
    """Undisturbed trajectory: every action is the next observed state; the last one holds still."""
    steps = []
    for index, (pose, gripper) in enumerate(zip(poses, grippers, strict=True)):
        next_index = min(index + 1, len(poses) - 1)
        steps.append(Step(pose, gripper, poses[next_index], grippers[next_index]))
    return steps


def add_disturbance(
    poses: list[np.ndarray],
    grippers: list[bool],
    rng: np.random.Generator,
    max_kicks: int = 5,
    keep_frames: Sequence[int] = (),
) -> list[Step]:
    """A local disturbance: the EE is pushed off the reference for a few frames, then actions bring it back.

    During the push the actions command a bounded step back toward the reference, but the observed pose drifts
    by a kick of at most one step size; afterwards a recovery path rejoins the reference a few frames ahead.
    Consecutive observed poses stay within the step bounds. Frames in ``keep_frames`` (the waypoints) are never
    skipped: the disturbance happens between them.
    """
    kicks = int(rng.integers(2, max_kicks + 1))
    starts = [
        start
        for start in range(1, len(poses) - kicks - 4)
        if not any(start - 1 <= frame <= start + kicks + 3 for frame in keep_frames)
    ]
    if not starts:
        return steps_from_states(poses, grippers)
    start = int(rng.choice(starts))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    kick = make_pose(
        direction * rng.uniform(0.4, 0.9) * MAX_STEP_TRANSLATION,
        Rotation.from_rotvec(axis * rng.uniform(0.3, 0.9) * MAX_STEP_ROTATION),
    )
    steps = steps_from_states(poses[: start + 1], grippers[: start + 1])
    observed = poses[start]
    gripper = grippers[start]
    reference_index = start
    for _ in range(kicks):
        reference_index = min(reference_index + 1, len(poses) - 1)
        command = _bounded_step(observed, poses[reference_index])
        steps[-1].action_T_world_ee = command
        pushed = observed.copy()
        pushed[:3, 3] = observed[:3, 3] + kick[:3, 3]
        pushed[:3, :3] = kick[:3, :3] @ observed[:3, :3]
        observed = pushed
        steps.append(Step(observed, gripper, observed, gripper))
    rejoin = min(reference_index + 3, len(poses) - 1)
    while rejoin < len(poses) - 1 and grippers[rejoin] != gripper:
        rejoin -= 1
    rejoin = max(rejoin, reference_index)
    recovery = resample_uniform(interpolate_linear(observed, poses[rejoin]))
    recovery_poses = list(recovery[1:]) + poses[rejoin + 1 :]
    recovery_grippers = [gripper] * (len(recovery) - 1) + grippers[rejoin + 1 :]
    if recovery_poses:
        steps[-1].action_T_world_ee = recovery_poses[0]
        steps[-1].action_gripper_open = recovery_grippers[0]
        steps.extend(steps_from_states(recovery_poses, recovery_grippers))
    return steps


def add_gripper_faults(steps: list[Step], fraction: float, rng: np.random.Generator) -> list[Step]:
    """On ``fraction`` of the frames the observed gripper state is wrong (paper appendix D: flipped gripper states).

    A fault at frame ``t`` flips only the *observed* gripper state of that frame; its pose and its action (the next
    pose and the right gripper command) stay as they were, so no frame is inserted and the motion never pauses.
    Frames next to a commanded gripper change are never faulted, and a fault never changes which object is held.
    """
    eligible = [
        index
        for index in range(1, len(steps) - 1)
        if steps[index - 1].gripper_open == steps[index].gripper_open == steps[index].action_gripper_open
        and steps[index - 1].action_gripper_open == steps[index].gripper_open
    ]
    count = min(len(eligible), int(round(fraction * len(steps))))
    if count == 0:
        return steps
    faulted = set(rng.choice(eligible, size=count, replace=False).tolist())
    return [
        Step(step.T_world_ee, not step.gripper_open, step.action_T_world_ee, step.action_gripper_open, True)
        if index in faulted
        else step
        for index, step in enumerate(steps)
    ]


def _bounded_step(T_from: np.ndarray, T_to: np.ndarray) -> np.ndarray:
    """The pose one bounded step (≤ 1 cm, ≤ 3°) from ``T_from`` toward ``T_to``."""
    translation, rotation = pose_distance(T_from, T_to)
    scale = max(translation / MAX_STEP_TRANSLATION, rotation / MAX_STEP_ROTATION, 1.0)
    fraction = 1.0 / scale
    return _stack(
        (T_from[:3, 3] + fraction * (T_to[:3, 3] - T_from[:3, 3]))[None],
        slerp_rotations(T_from[:3, :3], T_to[:3, :3], np.array([fraction])),
    )[0]


def _stack(positions: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    poses = np.zeros((len(positions), 4, 4))
    poses[:, :3, :3] = rotations
    poses[:, :3, 3] = positions
    poses[:, 3, 3] = 1.0
    return poses
