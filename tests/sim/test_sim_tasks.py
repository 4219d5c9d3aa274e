"""Every built-in task: the scripted demonstrator solves it, doing nothing does not."""

from __future__ import annotations

import pytest

from lerobot_instant_policy.sim.env import BulletTabletopEnv
from lerobot_instant_policy.sim.rollout import run_episode
from lerobot_instant_policy.sim.task_api import task_names

TASKS = task_names()


def test_at_least_ten_tasks():
    assert len(TASKS) >= 10


@pytest.mark.parametrize("task", TASKS)
def test_scripted_demo_succeeds_and_doing_nothing_fails(task):
    env = BulletTabletopEnv(task, observe_pointcloud=False)
    try:
        for seed in (1000, 1001):
            episode = run_episode(env, seed, "scripted")
            assert episode.success, f"scripted {task} failed on seed {seed}"
            assert episode.num_frames < env._max_episode_steps
        idle = run_episode(env, 1000, "idle")
        assert not idle.success and idle.num_frames == env._max_episode_steps
    finally:
        env.close()


@pytest.mark.slow
def test_scripted_success_table_over_twenty_seeds():
    from lerobot_instant_policy.sim.recording import check

    for row in check(TASKS, episodes=20, seed=0):
        assert row["scripted_success"] >= 0.95, row
        assert row["idle_success"] == 0.0, row
