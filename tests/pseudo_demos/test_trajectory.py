"""Gripper motion: interpolation, uniform resampling, disturbances and gripper faults (``pseudo_demos.trajectory``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.geometry.se3 import make_pose, pose_distance
from lerobot_instant_policy.pseudo_demos.trajectory import (
    MAX_STEP_ROTATION,
    MAX_STEP_TRANSLATION,
    Step,
    add_disturbance,
    add_gripper_faults,
    interpolate_cubic,
    interpolate_linear,
    interpolate_spherical,
    resample_uniform,
    steps_from_states,
)

SLACK = 1e-6


def _assert_bounded_steps(poses) -> None:
    poses = np.asarray(poses)
    translation, rotation = pose_distance(poses[:-1], poses[1:])
    assert translation.max() <= MAX_STEP_TRANSLATION + SLACK, translation.max()
    assert rotation.max() <= MAX_STEP_ROTATION + SLACK, np.rad2deg(rotation.max())


def _assert_same_pose(a, b, atol=1e-9) -> None:
    translation, rotation = pose_distance(np.asarray(a), np.asarray(b))
    assert translation <= atol and rotation <= max(atol, 1e-6)


START = make_pose([0.3, -0.1, 0.3], Rotation.from_euler("xyz", [np.pi, 0.1, 0.2]))
END = make_pose([0.55, 0.12, 0.08], Rotation.from_euler("xyz", [np.pi - 0.4, -0.3, 1.2]))


def _dense_paths():
    return {
        "linear": interpolate_linear(START, END),
        "cubic": interpolate_cubic(START, END, np.array([[0.0, 0.1, 0.15], [0.05, -0.1, 0.2]])),
        "spherical": interpolate_spherical(START, END, np.array([0.45, 0.0, 0.0])),
    }


@pytest.mark.parametrize("kind", ["linear", "cubic", "spherical"])
def test_dense_paths_start_and_end_at_the_given_poses(kind):
    dense = _dense_paths()[kind]
    _assert_same_pose(dense[0], START)
    _assert_same_pose(dense[-1], END)
    # proper rotations all along
    np.testing.assert_allclose(np.linalg.det(dense[:, :3, :3]), 1.0, atol=1e-9)


@pytest.mark.parametrize("kind", ["linear", "cubic", "spherical"])
def test_resample_uniform_respects_step_bounds_and_keeps_endpoints(kind):
    dense = _dense_paths()[kind]
    resampled = resample_uniform(dense)
    assert resampled.shape[1:] == (4, 4)
    assert len(resampled) >= 2
    _assert_bounded_steps(resampled)
    _assert_same_pose(resampled[0], dense[0])
    _assert_same_pose(resampled[-1], dense[-1], atol=1e-7)
    # steps are equal in the path metric, so not wastefully short: the path length sets the frame count
    translation, rotation = pose_distance(dense[:-1], dense[1:])
    cost = np.maximum(translation / MAX_STEP_TRANSLATION, rotation / MAX_STEP_ROTATION).sum()
    assert len(resampled) - 1 == int(np.ceil(cost - 1e-9))


def test_resample_uniform_rotation_limited_path():
    """2 cm of translation but 90° of rotation: spacing must be set by the 3° bound (≥ 30 steps)."""
    start = make_pose([0.4, 0.0, 0.2], Rotation.from_euler("x", np.pi))
    end = make_pose([0.42, 0.0, 0.2], Rotation.from_euler("x", np.pi) * Rotation.from_euler("z", np.pi / 2))
    resampled = resample_uniform(interpolate_linear(start, end))
    _assert_bounded_steps(resampled)
    _assert_same_pose(resampled[-1], end, atol=1e-7)
    assert 31 <= len(resampled) <= 32
    _, rotation = pose_distance(resampled[:-1], resampled[1:])
    np.testing.assert_allclose(rotation, rotation.mean(), atol=1e-3 * MAX_STEP_ROTATION)  # uniform steps


def test_resample_uniform_zero_length_path_is_one_frame():
    dense = np.repeat(START[None], 10, axis=0)
    resampled = resample_uniform(dense)
    assert resampled.shape == (1, 4, 4)
    np.testing.assert_allclose(resampled[0], START)


def test_interpolate_spherical_keeps_constant_radius():
    center = np.array([0.5, 0.0, 0.1])
    start = make_pose(center + [0.1, 0.0, 0.0], Rotation.from_euler("x", np.pi))
    end = make_pose(center + [0.0, 0.06, 0.08], Rotation.from_euler("xz", [np.pi, 1.0]))
    dense = interpolate_spherical(start, end, center)
    radii = np.linalg.norm(dense[:, :3, 3] - center, axis=1)
    np.testing.assert_allclose(radii, 0.1, atol=1e-9)
    # and it is an arc, not the chord: the midpoint is off the straight line
    chord_mid = (start[:3, 3] + end[:3, 3]) / 2
    assert np.linalg.norm(dense[len(dense) // 2, :3, 3] - chord_mid) > 0.01
    # resampled, it still stays on the sphere up to the chord sagitta of a ≤ 1 cm step
    resampled = resample_uniform(dense)
    _assert_bounded_steps(resampled)
    np.testing.assert_allclose(np.linalg.norm(resampled[:, :3, 3] - center, axis=1), 0.1, atol=1e-3)


def test_steps_from_states_actions_are_next_states():
    poses = list(resample_uniform(interpolate_linear(START, END)))
    grippers = [True] * (len(poses) // 2) + [False] * (len(poses) - len(poses) // 2)
    steps = steps_from_states(poses, grippers)
    assert len(steps) == len(poses)
    for index, step in enumerate(steps):
        np.testing.assert_array_equal(step.T_world_ee, poses[index])
        assert step.gripper_open == grippers[index]
        assert not step.gripper_fault
        nxt = min(index + 1, len(poses) - 1)
        np.testing.assert_array_equal(step.action_T_world_ee, poses[nxt])
        assert step.action_gripper_open == grippers[nxt]
    np.testing.assert_array_equal(steps[-1].action_T_world_ee, steps[-1].T_world_ee)  # last holds
    assert steps[-1].action_gripper_open == steps[-1].gripper_open


def _reference(with_change: bool = True):
    """A long reference: 40-odd frames of motion, a gripper change at a waypoint, more motion."""
    middle = make_pose([0.5, 0.1, 0.1], Rotation.from_euler("x", np.pi))
    first = list(resample_uniform(interpolate_linear(START, middle)))
    second = list(resample_uniform(interpolate_linear(middle, END)))
    poses = first + [middle] + second[1:] if with_change else first + second[1:]
    grippers = [True] * len(first) + [not with_change] * (len(poses) - len(first))
    return poses, grippers


@pytest.mark.parametrize("seed", range(6))
def test_add_disturbance_pushes_then_recovers(seed):
    poses, grippers = _reference()
    assert len(poses) > 40
    steps = add_disturbance(poses, grippers, np.random.default_rng(seed))
    observed = [step.T_world_ee for step in steps]
    _assert_bounded_steps(observed)
    # the push: some action commands a pose the EE then does not reach
    pushed = [
        index
        for index in range(len(steps) - 1)
        if pose_distance(steps[index].action_T_world_ee, steps[index + 1].T_world_ee)[0] > 1e-6
    ]
    assert pushed
    # every commanded action is itself a bounded step from the observed pose
    _assert_bounded_steps_pairs([(step.T_world_ee, step.action_T_world_ee) for step in steps])
    # ends where the reference ends, gripper included, holding still
    _assert_same_pose(steps[-1].T_world_ee, poses[-1])
    assert steps[-1].gripper_open == grippers[-1]
    _assert_same_pose(steps[-1].action_T_world_ee, poses[-1])
    # the off-reference frames really are off the reference
    off = [min(pose_distance(np.stack(poses), step.T_world_ee)[0]) for step in steps]
    assert max(off) > 1e-3
    # the gripper changes as often as in the reference
    changes = sum(a.gripper_open != b.gripper_open for a, b in zip(steps[:-1], steps[1:]))
    assert changes == 1


def _assert_bounded_steps_pairs(pairs) -> None:
    for current, action in pairs:
        translation, rotation = pose_distance(current, action)
        assert translation <= MAX_STEP_TRANSLATION + SLACK
        assert rotation <= MAX_STEP_ROTATION + SLACK


def test_add_disturbance_short_path_is_undisturbed():
    poses = list(resample_uniform(interpolate_linear(START, make_pose([0.32, -0.1, 0.3], START[:3, :3]))))
    assert len(poses) < 8
    steps = add_disturbance(poses, [True] * len(poses), np.random.default_rng(0))
    for step, pose in zip(steps, poses, strict=True):
        np.testing.assert_array_equal(step.T_world_ee, pose)


@pytest.mark.parametrize("seed", range(12))
def test_add_disturbance_never_skips_kept_frames(seed):
    """With the waypoint frames kept, every waypoint pose is still visited and the gripper changes there."""
    poses, grippers = _reference()
    change = grippers.index(False)  # first closed frame; the waypoint frame is the one before it
    waypoint = change - 1
    steps = add_disturbance(poses, grippers, np.random.default_rng(seed), keep_frames=[waypoint, len(poses) - 1])
    observed = np.stack([step.T_world_ee for step in steps])
    _assert_bounded_steps(observed)
    assert pose_distance(observed, poses[waypoint])[0].min() < 1e-12  # the waypoint is reached exactly
    reference = np.stack(poses)
    off = [pose_distance(reference, pose)[0].min() for pose in observed]
    assert max(off) > 1e-3  # the disturbance did happen
    flips = [i for i in range(1, len(steps)) if steps[i].gripper_open != steps[i - 1].gripper_open]
    assert len(flips) == 1
    _assert_same_pose(steps[flips[0]].T_world_ee, poses[change])
    _assert_same_pose(steps[flips[0] - 1].T_world_ee, poses[waypoint])


def test_add_disturbance_without_room_is_undisturbed():
    poses, grippers = _reference()
    steps = add_disturbance(poses, grippers, np.random.default_rng(0), keep_frames=range(len(poses)))
    assert len(steps) == len(poses)
    for step, pose in zip(steps, poses, strict=True):
        np.testing.assert_array_equal(step.T_world_ee, pose)


def _gripper_reference():
    """Steps with two commanded gripper changes (close then open), each at a repeated waypoint pose."""
    a = make_pose([0.3, 0.0, 0.3], Rotation.from_euler("x", np.pi))
    b = make_pose([0.5, 0.0, 0.05], Rotation.from_euler("x", np.pi))
    c = make_pose([0.5, 0.2, 0.2], Rotation.from_euler("x", np.pi))
    first = list(resample_uniform(interpolate_linear(a, b)))
    second = list(resample_uniform(interpolate_linear(b, c)))
    poses = first + [b] + second[1:] + [c]
    grippers = [True] * len(first) + [False] * len(second) + [True]
    return steps_from_states(poses, grippers)


@pytest.mark.parametrize("seed", range(4))
def test_add_gripper_faults_flip_the_observed_state_in_place(seed):
    steps = _gripper_reference()
    fraction = 0.15
    faulted = add_gripper_faults(steps, fraction, np.random.default_rng(seed))
    # no frame is inserted: the motion never pauses for a fault
    assert len(faulted) == len(steps)
    fault_positions = [index for index, step in enumerate(faulted) if step.gripper_fault]
    assert len(fault_positions) == int(round(fraction * len(steps)))
    for index, (fault, original) in enumerate(zip(faulted, steps, strict=True)):
        if index not in fault_positions:
            assert fault is original
            continue
        # same pose and the same action (pose and right gripper command); only the observed gripper is wrong
        assert fault.T_world_ee is original.T_world_ee
        assert fault.action_T_world_ee is original.action_T_world_ee
        assert fault.action_gripper_open == original.action_gripper_open
        assert fault.gripper_open != original.gripper_open
        # never next to a commanded gripper change
        assert steps[index - 1].gripper_open == original.gripper_open == original.action_gripper_open
        assert steps[index - 1].action_gripper_open == original.gripper_open


def test_add_gripper_faults_edge_cases():
    steps = _gripper_reference()
    assert add_gripper_faults(steps, 0.0, np.random.default_rng(0)) is steps
    # asking for more faults than eligible frames faults every eligible frame, never a change frame
    everything = add_gripper_faults(steps, 5.0, np.random.default_rng(0))
    eligible = [
        index
        for index in range(1, len(steps) - 1)
        if steps[index - 1].gripper_open == steps[index].gripper_open == steps[index].action_gripper_open
        and steps[index - 1].action_gripper_open == steps[index].gripper_open
    ]
    assert sum(step.gripper_fault for step in everything) == len(eligible) < len(steps) - 2
    # deterministic for a seed
    first = add_gripper_faults(steps, 0.2, np.random.default_rng(5))
    second = add_gripper_faults(steps, 0.2, np.random.default_rng(5))
    assert [s.gripper_fault for s in first] == [s.gripper_fault for s in second]


def test_step_default_is_not_a_fault():
    pose = np.eye(4)
    assert Step(pose, True, pose, True).gripper_fault is False
