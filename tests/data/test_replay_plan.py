"""Replay plans (``data/replay_plan.py``): where two objects move independently between the demonstration and the
live scene, the per-object plan grasps where the grasped object is now and releases where the other one is now; one
motion for the whole cloud cannot do both."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_demos import object_cloud, object_pose

from lerobot_instant_policy.contract import NUM_POINTS
from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.data.replay_plan import plan_replay, split_objects
from lerobot_instant_policy.geometry.registration import RegistrationConfig
from lerobot_instant_policy.geometry.se3 import look_rotation, make_pose, pose_to_pos_quat

MUG, DUCK = "pb/mug", "pb/duck"
CLOSE, RELEASE = 2, 7  # the frames where the demonstration's gripper closes on the mug and opens above the duck
REGISTRATION = RegistrationConfig(yaw_only=True)


def scene_cloud(T_world_mug: np.ndarray, T_world_duck: np.ndarray, seed: int) -> np.ndarray:
    """``(NUM_POINTS, 3)``: half the points on the mug, half on the duck."""
    half = NUM_POINTS // 2
    return np.concatenate([object_cloud(T_world_mug, seed, object_id=MUG)[:half],
                           object_cloud(T_world_duck, seed + 1, object_id=DUCK)[:half]])


def carry_actions(T_world_mug: np.ndarray, T_world_duck: np.ndarray, grasp_open: bool = False) -> np.ndarray:
    """``(9, 8)``: down onto the mug, close (frame 2), lift, carry over the duck, lower, open (frame 7), up.
    ``grasp_open``: the gripper never closes (no grasp and release)."""
    mug, duck = T_world_mug[:3, 3], T_world_duck[:3, 3]
    waypoints = [(mug, 0.20, 1), (mug, 0.06, 1), (mug, 0.06, 0), (mug, 0.20, 0), ((mug + duck) / 2, 0.20, 0),
                 (duck, 0.20, 0), (duck, 0.12, 0), (duck, 0.12, 1), (duck, 0.25, 1)]
    down = look_rotation(np.array([0.0, 0.0, -1.0]), yaw=0.0)
    rows = []
    for xy, height, gripper in waypoints:
        position, quat = pose_to_pos_quat(make_pose(np.array([xy[0], xy[1], height]), down))
        rows.append(np.concatenate([position, quat, [1.0 if grasp_open else gripper]]))
    return np.asarray(rows, dtype=np.float32)


def carry_demo(T_world_mug: np.ndarray, T_world_duck: np.ndarray, seed: int, grasp_open: bool = False) -> Demonstration:
    action = carry_actions(T_world_mug, T_world_duck, grasp_open)
    state = np.concatenate([action[:1], action[:-1]])
    points = np.repeat(scene_cloud(T_world_mug, T_world_duck, seed)[None], len(action), axis=0)
    return Demonstration(points_world=points, state=state, action=action, task="put_on_duck")


def test_split_objects_finds_each_object_and_drops_stray_points():
    cloud = scene_cloud(object_pose(0.45, 0.1, 0.0), object_pose(0.55, -0.12, 30.0), seed=0)
    stray = np.array([[0.9, 0.9, 0.5]], dtype=np.float32)
    objects = split_objects(np.concatenate([cloud, stray]))
    assert sorted(len(points) for points in objects) == [NUM_POINTS // 2, NUM_POINTS // 2]
    assert {float(points[:, 1].mean() > 0) for points in objects} == {0.0, 1.0}  # one on each side


def test_per_object_plan_grasps_at_the_grasped_object_and_releases_at_the_other():
    demo = carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0)
    T_world_mug_now, T_world_duck_now = object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0)
    cloud_now = scene_cloud(T_world_mug_now, T_world_duck_now, seed=5)
    expected = carry_actions(T_world_mug_now, T_world_duck_now)

    plan = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, per_object=True)
    assert plan.T_now_demo_per_action is not None and len(plan.object_fits) == 2
    for frame in (0, 1, CLOSE, RELEASE, 8):  # on the mug up to the grasp, on the duck from the release
        np.testing.assert_allclose(plan.actions[frame, :3], expected[frame, :3], atol=0.005)
    np.testing.assert_array_equal(plan.actions[:, 7], demo.action[:, 7])
    steps = np.linalg.norm(np.diff(plan.actions[:, :3], axis=0), axis=1)
    demo_steps = np.linalg.norm(np.diff(expected[:, :3], axis=0), axis=1)
    assert steps.max() < demo_steps.max() + 0.05  # the carry is blended, not a jump from one object to the other

    whole = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION)
    errors = [np.linalg.norm(whole.actions[frame, :3] - expected[frame, :3]) for frame in (CLOSE, RELEASE)]
    assert max(errors) > 0.03  # one motion cannot put the grasp and the release where both objects are now


@pytest.mark.parametrize("grasp_open, cloud_now", [
    (True, scene_cloud(object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0), seed=5)),
    (False, object_cloud(object_pose(0.50, 0.02, 30.0), seed=5, object_id=MUG)),
])
def test_per_object_falls_back_to_the_whole_cloud_without_a_grasp_or_a_second_object(grasp_open, cloud_now):
    demo = carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0, grasp_open=grasp_open)
    per_object = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, per_object=True)
    whole = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION)
    assert per_object.T_now_demo_per_action is None and per_object.object_fits == ()
    np.testing.assert_array_equal(per_object.actions, whole.actions)


def test_no_demonstrations_is_a_clear_error():
    with pytest.raises(ValueError, match="no demonstrations of task 'put_on_duck' to replay"):
        plan_replay("put_on_duck", [], np.zeros((10, 3)), REGISTRATION)
