"""Replay plans (``replay/plan.py``): where two objects move independently between the demonstration and the
live scene, the per-object and the anchored plans grasp where the grasped object is now and release where the other
one is now; one motion for the whole cloud cannot do both. The anchored plan does the same for a demonstration that
never grasps (a push, a reach), where the per-object plan falls back to the whole cloud. By consensus the plan is the
one whose demonstrations agree in the live scene: the whole cloud for a square block pushed onto a square plate,
which the anchored plan registers each on its own and turns a quarter, and the anchored plan where objects moved
apart."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_demos import (
    MUG,
    carry_actions,
    carry_demo,
    object_cloud,
    object_pose,
    push_actions,
    push_cloud,
    push_demo,
    push_layout,
    scene_cloud,
)

from lerobot_instant_policy.contract import NUM_POINTS
from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.geometry.registration import RegistrationConfig
from lerobot_instant_policy.replay.agreement import plans_disagreement
from lerobot_instant_policy.replay.plan import (
    REPLAY_PLANS,
    plan_each,
    plan_replay,
    replay_plan_name,
    split_objects,
    transform_pose_actions,
)
from lerobot_instant_policy.replay.segments import plan_is_wrong

CLOSE, RELEASE = 2, 7  # the frames where the demonstration's gripper closes on the mug and opens above the duck
REGISTRATION = RegistrationConfig(yaw_only=True)


def test_split_objects_finds_each_object_and_drops_stray_points():
    cloud = scene_cloud(object_pose(0.45, 0.1, 0.0), object_pose(0.55, -0.12, 30.0), seed=0)
    stray = np.array([[0.9, 0.9, 0.5]], dtype=np.float32)
    objects = split_objects(np.concatenate([cloud, stray]))
    assert sorted(len(points) for points in objects) == [NUM_POINTS // 2, NUM_POINTS // 2]
    assert {float(points[:, 1].mean() > 0) for points in objects} == {0.0, 1.0}  # one on each side


@pytest.mark.parametrize("plan_name", ["per_object", "anchored"])
def test_per_object_plan_grasps_at_the_grasped_object_and_releases_at_the_other(plan_name):
    demo = carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0)
    T_world_mug_now, T_world_duck_now = object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0)
    cloud_now = scene_cloud(T_world_mug_now, T_world_duck_now, seed=5)
    expected = carry_actions(T_world_mug_now, T_world_duck_now)

    plan = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, plan_name)
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
    per_object = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, "per_object")
    whole = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION)
    assert per_object.T_now_demo_per_action is None and per_object.object_fits == ()
    np.testing.assert_array_equal(per_object.actions, whole.actions)


def test_anchored_plan_approaches_each_object_where_it_is_now_without_a_grasp():
    """A demonstration that touches the mug, then the duck, gripper open throughout (a push, a reach): each touch
    follows its own object, while the per-object plan has no grasp to structure and replays it whole."""
    demo = carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0, grasp_open=True)
    T_world_mug_now, T_world_duck_now = object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0)
    cloud_now = scene_cloud(T_world_mug_now, T_world_duck_now, seed=5)
    expected = carry_actions(T_world_mug_now, T_world_duck_now, grasp_open=True)

    anchored = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, "anchored")
    for frame in (1, 2, 6, 7, 8):  # at the mug, then at the duck
        np.testing.assert_allclose(anchored.actions[frame, :3], expected[frame, :3], atol=0.005)
    per_object = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, "per_object")
    assert per_object.T_now_demo_per_action is None
    errors = [np.linalg.norm(per_object.actions[frame, :3] - expected[frame, :3]) for frame in (1, 7)]
    assert max(errors) > 0.03  # one motion cannot touch both where they are now


def test_anchored_plan_of_a_scene_moved_whole_is_the_demonstration_moved_whole():
    """Both objects moved by one yaw and shift: every segment's anchor moves by it, so the plan is the demonstration's
    actions moved by that one motion (the whole-cloud plan's answer), orientation included."""
    T_world_mug, T_world_duck = object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0)
    demo = carry_demo(T_world_mug, T_world_duck, seed=0)
    T_moved = object_pose(0.04, -0.03, 25.0)
    cloud_now = scene_cloud(T_moved @ T_world_mug, T_moved @ T_world_duck, seed=5)
    anchored = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, "anchored")
    expected = transform_pose_actions(T_moved, demo.action)
    np.testing.assert_allclose(anchored.actions[:, :3], expected[:, :3], atol=0.005)
    alignment = np.abs(np.sum(anchored.actions[:, 3:7] * expected[:, 3:7], axis=1))
    assert alignment.min() > np.cos(np.deg2rad(4.0) / 2)  # within 4 degrees (the mug's yaw fits to about 3)
    np.testing.assert_array_equal(anchored.actions[:, 7], demo.action[:, 7])


def test_anchored_plan_falls_back_to_the_whole_cloud_where_nothing_is_approached():
    """A demonstration that stays 40 cm above the table and never acts: no segment approaches an object."""
    demo = carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0, grasp_open=True)
    high = demo.action.copy()
    high[:, 2] = 0.4 + 0.01 * np.arange(len(high))
    demo = Demonstration(points_world=demo.points_world, state=high, action=high, task="put_on_duck")
    cloud_now = scene_cloud(object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0), seed=5)
    anchored = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION, "anchored")
    whole = plan_replay("put_on_duck", [demo], cloud_now, REGISTRATION)
    assert anchored.T_now_demo_per_action is None
    np.testing.assert_array_equal(anchored.actions, whole.actions)


def test_an_unknown_plan_and_both_switches_are_clear_errors():
    with pytest.raises(ValueError, match="unknown replay plan 'segments'"):
        plan_replay("put_on_duck", [], np.zeros((10, 3)), REGISTRATION, "segments")
    for switches in ((True, True, False), (True, False, True), (False, True, True)):
        with pytest.raises(ValueError, match="not two"):
            replay_plan_name(*switches)
    assert [replay_plan_name(False, False), replay_plan_name(True, False), replay_plan_name(False, True),
            replay_plan_name(False, False, True)] == list(REPLAY_PLANS)


def test_no_demonstrations_is_a_clear_error():
    with pytest.raises(ValueError, match="no demonstrations of task 'put_on_duck' to replay"):
        plan_replay("put_on_duck", [], np.zeros((10, 3)), REGISTRATION)


def _push_scenes(count: int):
    """``count`` push scenes: two demonstrations and a live layout, every heading and yaw drawn anew."""
    for trial in range(count):
        rng = np.random.default_rng(trial)
        demos = [push_demo(*push_layout(0.45, -0.1, *rng.uniform((0, 0, 0), (360, 90, 90))), seed=10 * trial + index)
                 for index in range(2)]
        yield demos, push_layout(0.5, 0.0, *rng.uniform((0, 0, 0), (360, 90, 90)))


def test_consensus_pushes_a_square_block_from_the_face_its_layout_names():
    """Block and plate are square: registered each on its own (anchored), the block's quarter turns fit alike and
    the push starts from a wrong face; the two demonstrations' plans part there, the whole-cloud plans agree (the
    plate fixes the turn) and are right."""
    for demos, live in _push_scenes(3):
        cloud_now, truth = push_cloud(*live, seed=99), push_actions(*live)
        anchored = plan_each("slide_block", demos, cloud_now, REGISTRATION, "anchored")
        whole = plan_each("slide_block", demos, cloud_now, REGISTRATION, "whole")
        assert plan_is_wrong(plan_replay("slide_block", demos, cloud_now, REGISTRATION, "anchored").actions, truth)
        assert plans_disagreement([plan.actions for plan in anchored]) > 0.03
        assert plans_disagreement([plan.actions for plan in whole]) < 0.02
        consensus = plan_replay("slide_block", demos, cloud_now, REGISTRATION, "consensus")
        assert not plan_is_wrong(consensus.actions, truth)
        np.testing.assert_array_equal(consensus.actions,
                                      plan_replay("slide_block", demos, cloud_now, REGISTRATION, "whole").actions)


def test_consensus_keeps_the_anchored_plan_where_objects_moved_apart():
    """A mug put on a duck that moved apart between the demonstrations and now, without a grasp to structure (the
    per-object plan falls back to the whole cloud): the whole-cloud plans part, the anchored ones agree."""
    demos = [carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0, grasp_open=True),
             carry_demo(object_pose(0.40, 0.05, -20.0), object_pose(0.60, -0.15, 40.0), seed=3, grasp_open=True)]
    mug_now, duck_now = object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0)
    cloud_now = scene_cloud(mug_now, duck_now, seed=5)
    consensus = plan_replay("put_on_duck", demos, cloud_now, REGISTRATION, "consensus")
    np.testing.assert_array_equal(consensus.actions,
                                  plan_replay("put_on_duck", demos, cloud_now, REGISTRATION, "anchored").actions)
    expected = carry_actions(mug_now, duck_now, grasp_open=True)
    whole = plan_replay("put_on_duck", demos, cloud_now, REGISTRATION, "whole")
    for frame in (1, 7):  # down at the mug, down at the duck
        assert np.linalg.norm(consensus.actions[frame, :3] - expected[frame, :3]) < 0.01
    assert max(np.linalg.norm(whole.actions[frame, :3] - expected[frame, :3]) for frame in (1, 7)) > 0.03


def test_consensus_of_one_demonstration_is_the_anchored_plan():
    demos, live = next(_push_scenes(1))
    cloud_now = push_cloud(*live, seed=99)
    np.testing.assert_array_equal(plan_replay("slide_block", demos[:1], cloud_now, REGISTRATION, "consensus").actions,
                                  plan_replay("slide_block", demos[:1], cloud_now, REGISTRATION, "anchored").actions)
