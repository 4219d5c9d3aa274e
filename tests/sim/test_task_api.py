"""The public task API: a task defined in this file is registered, built by the env, solved by its scripted
demonstration, picked by the LeRobot env config and recorded as a dataset."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_instant_policy.sim import Part, ScriptedWaypoint, Task, get_task, register_task, task_names, top_down_pose
from lerobot_instant_policy.sim.env import BulletTabletopEnv
from lerobot_instant_policy.sim.rollout import run_episode


@register_task
class PushCylinderForward(Task):
    """Push a puck at least 8 cm away from the robot (+x)."""

    name = "test_push_puck_forward"
    max_episode_steps = 80

    def build(self, scene, rng):
        self.start = np.array([rng.uniform(0.45, 0.5), rng.uniform(-0.1, 0.1)])
        self.puck = scene.add_compound([Part("cylinder", (0.025, 0.03))], (*self.start, 0.015), mass=0.1)

    def is_success(self, scene):
        return bool(scene.pose(self.puck)[0, 3] - self.start[0] > 0.08)

    def demonstration(self, scene):
        x, y = scene.pose(self.puck)[:2, 3]
        return [
            ScriptedWaypoint(top_down_pose((x - 0.06, y, 0.12)), gripper_open=False),
            ScriptedWaypoint(top_down_pose((x - 0.06, y, 0.012)), gripper_open=False),
            ScriptedWaypoint(top_down_pose((x + 0.08, y, 0.012)), gripper_open=False),
        ]


def test_user_task_is_registered_and_listed():
    assert "test_push_puck_forward" in task_names()
    assert get_task("test_push_puck_forward") is PushCylinderForward
    assert "pick_and_lift" in task_names()


def test_user_task_runs_through_the_env():
    env = BulletTabletopEnv("test_push_puck_forward")
    try:
        observation, _ = env.reset(seed=0)
        puck = env.scene.pose(env.task_impl.puck)[:3, 3]
        assert np.linalg.norm(observation["pointcloud"].mean(axis=0)[:2] - puck[:2]) < 0.02
        assert run_episode(env, 0, "scripted").success
        assert not run_episode(env, 0, "idle").success
    finally:
        env.close()


def test_user_task_through_the_lerobot_env_config_and_the_recorder(tmp_path):
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.data.lerobot_format import read_episode
    from lerobot_instant_policy.sim.configuration_bullet_tabletop import BulletTabletopEnvConfig
    from lerobot_instant_policy.sim.recording import record

    vector_env = BulletTabletopEnvConfig(task="test_push_puck_forward").create_envs(1)["test_push_puck_forward"][0]
    try:
        assert list(vector_env.call("task")) == ["test_push_puck_forward"]
        assert vector_env.call("_max_episode_steps")[0] == 80
    finally:
        vector_env.close()
    summary = record("test_push_puck_forward", 1, tmp_path / "puck", "local/puck", seed=3)
    assert summary["episodes"] == 1
    episode = read_episode(LeRobotDataset("local/puck", root=tmp_path / "puck"), 0)
    assert episode["task"] == "test_push_puck_forward"
    assert episode["points"].shape[1:] == (2048, 3)


def test_registration_errors():
    with pytest.raises(ValueError, match="already registered"):

        @register_task
        class Clash(PushCylinderForward):
            name = "pick_and_lift"

    with pytest.raises(TypeError, match="Task subclass"):
        register_task(object)

    with pytest.raises(ValueError, match="non-empty class attribute `name`"):

        @register_task
        class Nameless(Task):
            def build(self, scene, rng): ...
            def is_success(self, scene): ...
            def demonstration(self, scene): ...
