"""The workbench probes' shared pieces (``workbench.replay_episodes``): seed lists, a checkpoint loaded with its replay
planned as named, an episode started with its replay planned, and the replay read by control step."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from lerobot_instant_policy.replay.plan import REPLAY_PLANS, ReplaySource
from lerobot_instant_policy.replay.priors import plan_onto_live
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from workbench.replay_episodes import episode_action, replay_policy, seed_list, start_episode
from workbench.scripts.demo_end_margin import scripted_demonstrations


def test_seed_lists_are_inclusive_ranges_or_comma_lists():
    assert seed_list("1000-1003") == [1000, 1001, 1002, 1003]
    assert seed_list("0,100,200") == [0, 100, 200]
    assert seed_list("7") == [7]


@pytest.mark.parametrize("plan", REPLAY_PLANS)
def test_the_policy_plans_its_replay_as_named_with_the_fields_given(plan):
    policy = replay_policy(SHIPPED_CHECKPOINT, plan, replay_init_strength=0.25, num_demos=3)
    assert policy.config.replay_plan() == plan
    assert (policy.config.replay_init_strength, policy.config.num_demos, policy.config.device) == (0.25, 3, "cpu")
    assert not policy.training


def test_the_replay_is_read_by_control_step_and_its_last_action_holds():
    plan = np.arange(3 * 8, dtype=np.float32).reshape(3, 8)
    actions = [episode_action(None, plan, step, {}, "any") for step in range(5)]
    np.testing.assert_array_equal(np.stack(actions), plan[[0, 1, 2, 2, 2]])


def test_an_episode_starts_from_its_seed_with_the_replay_planned_onto_its_first_cloud_and_the_policy_handed_the_demos():
    demonstrations = scripted_demonstrations("push_button", 0, 1, "instant")
    policy = replay_policy(SHIPPED_CHECKPOINT, "whole")
    env = BulletTabletopEnv("push_button", BulletTabletopConfig(render_size=(64, 64)))
    try:
        observation, plan = start_episode(env, "push_button", demonstrations, "whole", 1000, policy)
        drawn = torch.rand(3)
        again, replanned = start_episode(env, "push_button", demonstrations, "whole", 1000, policy)
        np.testing.assert_array_equal(torch.rand(3), drawn)  # the policy's noise seeded by the episode's seed
        other, _ = start_episode(env, "push_button", demonstrations, "whole", 1001)
    finally:
        env.close()
    np.testing.assert_array_equal(again["pointcloud"], observation["pointcloud"])
    np.testing.assert_array_equal(replanned, plan)
    assert not np.array_equal(other["pointcloud"], observation["pointcloud"])
    expected = plan_onto_live("push_button", [ReplaySource.of(demonstrations[0])], observation["pointcloud"], "whole")
    np.testing.assert_array_equal(plan, expected.actions)
    assert policy.task_context("push_button") is not None  # handed the demonstrations
