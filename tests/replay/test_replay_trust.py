"""A replay plan's trust (``replay/trust.py``): two demonstrations registered rightly into the live scene agree on its
path whatever their pace; one whose actions do not belong to its cloud (a wrong registration's effect) disagrees by
about how far it is off; the strength a prediction starts from rises with the distrust."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_demos import carry_actions, carry_demo, object_pose, random_poses, scene_cloud

from lerobot_instant_policy.contract import poses_from_vectors, vectors_from_poses
from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.replay.agreement import path_disagreement
from lerobot_instant_policy.replay.plan import REPLAY_REGISTRATION, best_plan, plan_each, plan_replay
from lerobot_instant_policy.replay.trust import PlanTrust, plan_trust, trusted_strength

MUG_NOW, DUCK_NOW = object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0)


def _demos() -> list[Demonstration]:
    return [carry_demo(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0), seed=0),
            carry_demo(object_pose(0.40, 0.05, -20.0), object_pose(0.60, -0.15, 40.0), seed=3)]


def test_plan_replay_executes_the_best_of_each_demonstrations_plan():
    cloud_now = scene_cloud(MUG_NOW, DUCK_NOW, seed=5)
    for plan in ("whole", "per_object", "anchored"):
        candidates = plan_each("put_on_duck", _demos(), cloud_now, REPLAY_REGISTRATION, plan)
        assert [candidate.demo_index for candidate in candidates] == [0, 1]
        chosen = plan_replay("put_on_duck", _demos(), cloud_now, REPLAY_REGISTRATION, plan)
        np.testing.assert_array_equal(best_plan(candidates).actions, chosen.actions)
        assert chosen.fit_error == min(candidate.fit_error for candidate in candidates)


def test_demonstrations_registered_rightly_agree_and_fit():
    cloud_now = scene_cloud(MUG_NOW, DUCK_NOW, seed=5)
    candidates = plan_each("put_on_duck", _demos(), cloud_now, REPLAY_REGISTRATION, "anchored")
    trust = plan_trust(candidates, best_plan(candidates))
    assert trust.disagreement_m < 0.01 and trust.fit_m < 0.005
    # one demonstration: nothing to compare
    assert plan_trust(candidates[:1], candidates[0]).disagreement_m == 0.0


def test_a_demonstration_whose_actions_miss_its_scene_disagrees_by_how_far_it_is_off():
    T_world_mug, T_world_duck = object_pose(0.40, 0.05, -20.0), object_pose(0.60, -0.15, 40.0)
    off = 0.06  # its place 6 cm beyond the duck its cloud shows
    T_world_duck_acted = T_world_duck.copy()
    T_world_duck_acted[0, 3] += off
    action = carry_actions(T_world_mug, T_world_duck_acted)
    wrong = carry_demo(T_world_mug, T_world_duck, seed=3)
    wrong = Demonstration(points_world=wrong.points_world, state=np.concatenate([action[:1], action[:-1]]),
                          action=action, task=wrong.task)
    cloud_now = scene_cloud(MUG_NOW, DUCK_NOW, seed=5)
    candidates = plan_each("put_on_duck", [_demos()[0], wrong], cloud_now, REPLAY_REGISTRATION, "anchored")
    disagreement = plan_trust(candidates, best_plan(candidates)).disagreement_m
    assert 0.5 * off < disagreement < 1.5 * off


def test_disagreement_is_symmetric_ignores_pace_and_rigid_motion():
    first = carry_actions(MUG_NOW, DUCK_NOW)
    slower = np.repeat(first, 3, axis=0)  # the same path, three control steps a waypoint
    assert path_disagreement(first, slower) == pytest.approx(0.0, abs=1e-9)
    second = carry_actions(MUG_NOW, object_pose(0.52, -0.18, -25.0))
    assert path_disagreement(first, second) > 0.02
    assert path_disagreement(first, second) == pytest.approx(path_disagreement(second, first))
    T_moved = random_poses(1, seed=2, extent_m=0.5)[0]

    def moved(actions: np.ndarray) -> np.ndarray:
        T_world_ee, gripper_open = poses_from_vectors(actions)
        return vectors_from_poses(T_moved @ T_world_ee, gripper_open)

    assert path_disagreement(moved(first), moved(second)) == pytest.approx(path_disagreement(first, second), abs=1e-6)


def test_trusted_strength_rises_from_the_configured_strength_to_noise():
    distrust = np.linspace(0.0, 0.08, 33)
    strengths = [trusted_strength(PlanTrust(fit_m=0.001, disagreement_m=d), 0.125, (0.02, 0.05)) for d in distrust]
    assert strengths[0] == 0.125 and strengths[-1] == 1.0
    assert np.all(np.diff(strengths) >= 0)
    assert trusted_strength(PlanTrust(fit_m=0.035, disagreement_m=0.0), 0.125, (0.02, 0.05)) == pytest.approx(
        0.125 + 0.875 * 0.5)  # a poor fit counts as a disagreement does
    with pytest.raises(ValueError, match="distrust range"):
        trusted_strength(PlanTrust(0.0, 0.0), 0.125, (0.05, 0.02))
