"""The replay error against the demonstration of the same live scene (``evaluation/replay_error.py``): zero where
the plan is right, the displacement where one motion cannot follow two objects, a gripper change the plan lacks
counted as missed, and a plan off at a gripper change (or missing one) counted as wrong."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_demos import carry_demo, object_pose

from lerobot_instant_policy.contract import poses_from_vectors, vectors_from_poses
from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.evaluation.replay_error import THIRDS, error_quantiles, plan_error

DEMO_SCENE = (object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0))
LIVE_SCENE = (object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0))


@pytest.fixture(scope="module")
def context_and_live() -> tuple[list[Demonstration], Demonstration]:
    return [carry_demo(*DEMO_SCENE, seed=0)], carry_demo(*LIVE_SCENE, seed=5)


def test_the_anchored_plan_errs_little_at_every_bottleneck_where_the_whole_one_misses_the_release(context_and_live):
    context, live = context_and_live
    anchored = plan_error(context, live, "anchored")
    whole = plan_error(context, live, "whole")
    kinds = [row["kind"] for row in anchored["bottlenecks"]]
    assert kinds.count("gripper") == 2 and kinds[-1] == "end" and anchored["missed"] == 0
    acting = [row["translation_m"] for row in anchored["bottlenecks"] if row["kind"] != "waypoint"]
    assert len(acting) == 3 and max(acting) < 0.006  # the grasp, the release and the end where the objects are now
    whole_gripper = [row["translation_m"] for row in whole["bottlenecks"] if row["kind"] == "gripper"]
    assert max(whole_gripper) > 0.03
    summary = error_quantiles([anchored])
    assert summary["gripper"]["count"] == 2 and summary["all"]["count"] == len(anchored["bottlenecks"])
    assert summary["gripper"]["translation_mm"]["p90"] < 6.0
    assert summary["missed_gripper_changes"] == 0
    assert error_quantiles([anchored, whole])["plans"] == 2
    assert error_quantiles([anchored, whole])["wrong_plans"] == 1  # the whole plan, off at the release


def test_a_gripper_turned_half_a_turn_about_its_approach_axis_errs_no_rotation(context_and_live):
    context, live = context_and_live
    turned = live.action.copy()
    T_world_ee, gripper_open = poses_from_vectors(turned)
    T_world_ee[:, :3, :3] = T_world_ee[:, :3, :3] @ np.diag([-1.0, -1.0, 1.0])
    turned = Demonstration(points_world=live.points_world, state=live.state,
                           action=vectors_from_poses(T_world_ee, gripper_open).astype(np.float32), task=live.task)
    same, flipped = plan_error([live], live, "whole"), plan_error([live], turned, "whole")
    for row, flipped_row in zip(same["bottlenecks"], flipped["bottlenecks"], strict=True):
        assert flipped_row["rotation_rad"] == pytest.approx(row["rotation_rad"], abs=1e-3)


def test_a_gripper_change_the_plan_lacks_is_missed(context_and_live):
    context, live = context_and_live
    never_closes = Demonstration(points_world=context[0].points_world, state=context[0].state.copy(),
                                 action=context[0].action.copy(), task=context[0].task)
    never_closes.action[:, 7] = 1.0
    error = plan_error([never_closes], live, "anchored")
    assert error["missed"] == 2  # the close and the open
    assert all(row["kind"] != "gripper" for row in error["bottlenecks"])
    assert error_quantiles([error])["gripper"] == {"count": 0}
    assert error_quantiles([error])["wrong_plans"] == 1  # a plan that never grasps is wrong wherever it goes


def test_the_prior_is_measured_as_training_reads_it_per_third_of_the_live_episode(context_and_live):
    context, live = context_and_live
    itself = error_quantiles([plan_error([live], live, "whole")])["prior_vs_holding_still"]
    assert itself["frames"] == len(live.action)
    assert all(itself[name] < 0.01 for name in ("all", *THIRDS))  # its own plan is its actions, registered onto itself
    anchored = error_quantiles([plan_error(context, live, "anchored")])["prior_vs_holding_still"]
    whole = error_quantiles([plan_error(context, live, "whole")])["prior_vs_holding_still"]
    assert 0.0 < anchored["all"] < 0.5  # near the live actions, far nearer than holding still
    assert whole["last_third"] > 2 * anchored["last_third"]  # one motion carries the object to the wrong place
    chunks = plan_error(context, live, "anchored", horizon=4)["chunks"]
    assert chunks["prior_m"].shape == chunks["hold_m"].shape == (len(live.action),)
