"""The ``do_nothing`` lower-bound baseline: its action is the current state, it holds the robot still in
``bullet_tabletop``, it goes through LeRobot's factories, and ``lerobot-eval`` runs it (via the eval suite)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from lerobot.configs import FeatureType, PolicyFeature, PreTrainedConfig

from lerobot_instant_policy.baselines import processor_do_nothing
from lerobot_instant_policy.baselines.modeling_do_nothing import DoNothingPolicy
from lerobot_instant_policy.cli import eval_suite
from lerobot_instant_policy.contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.evaluation import suite


def make_do_nothing(**overrides):
    """``do_nothing`` built the way ``lerobot-eval --policy.type=do_nothing`` builds it (no pretrained path)."""
    from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors

    config = make_policy_config("do_nothing", device="cpu", **overrides)
    policy = get_policy_class("do_nothing")(config)
    preprocessor, postprocessor = make_pre_post_processors(config)
    return policy, preprocessor, postprocessor


def random_states(batch_size: int, seed: int = 0) -> torch.Tensor:
    """``(B, 8)`` float32 states: EE xyz, unit quaternion xyzw, gripper open flag."""
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(batch_size, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    gripper = rng.integers(0, 2, (batch_size, 1))
    return torch.from_numpy(np.concatenate([rng.uniform(-0.5, 0.5, (batch_size, 3)), quats, gripper], axis=1)).float()


def test_registered_and_resolved_by_lerobot_factories(monkeypatch):
    from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors

    assert "do_nothing" in PreTrainedConfig.get_known_choices()
    assert get_policy_class("do_nothing") is DoNothingPolicy
    config = make_policy_config("do_nothing")
    assert config.type == "do_nothing" and config.push_to_hub is False
    assert set(config.input_features) == {POINTCLOUD_KEY, STATE_KEY} and set(config.output_features) == {ACTION_KEY}

    calls = []
    original = processor_do_nothing.make_do_nothing_pre_post_processors

    def spy(*args, **kwargs):
        calls.append(args)
        return original(*args, **kwargs)

    monkeypatch.setattr(processor_do_nothing, "make_do_nothing_pre_post_processors", spy)
    preprocessor, postprocessor = make_pre_post_processors(config)
    assert len(calls) == 1 and calls[0][0] is config
    assert [type(step).__name__ for step in preprocessor.steps] == [
        "RenameObservationsProcessorStep", "AddBatchDimensionProcessorStep", "AddPointCloudBatchDimensionStep",
        "DeviceProcessorStep", "NormalizerProcessorStep"
    ]

    policy = DoNothingPolicy(config)
    assert policy.get_optim_params() == [] and list(policy.parameters()) == []
    with pytest.raises(RuntimeError, match="no trainable parameters"):
        policy.forward({STATE_KEY: random_states(1)})
    with pytest.raises(ValueError, match="n_obs_steps must be 1"):
        make_policy_config("do_nothing", n_obs_steps=2)


def test_action_is_the_state_through_the_processors():
    policy, preprocessor, postprocessor = make_do_nothing()
    states = random_states(3)
    batch = {STATE_KEY: states.clone(), POINTCLOUD_KEY: torch.rand(3, 2048, 3), "task": ["push_button"] * 3}
    policy.reset()
    for _ in range(2):  # no state carried between steps
        with torch.inference_mode():
            action = postprocessor(policy.select_action(preprocessor(batch)))
        assert action.shape == (3, 8) and action.dtype == torch.float32
        torch.testing.assert_close(action, states, rtol=0, atol=0)

    chunk = policy.predict_action_chunk({STATE_KEY: states})
    assert chunk.shape == (3, 1, 8) and chunk.dtype == torch.float32
    torch.testing.assert_close(chunk[:, 0], states, rtol=0, atol=0)

    double = states.double()
    action = policy.select_action({STATE_KEY: double})
    assert action.dtype == torch.float32 and action.data_ptr() != double.data_ptr()
    action += 1.0  # the action is a copy: changing it leaves the observation alone
    torch.testing.assert_close(double.float(), states, rtol=0, atol=0)


def test_bad_input_gives_clear_errors():
    policy, _, _ = make_do_nothing()
    with pytest.raises(KeyError, match=r"do_nothing needs 'observation.state' in the batch, got keys \['observation.pointcloud'\]"):
        policy.select_action({POINTCLOUD_KEY: torch.zeros(1, 2048, 3)})
    with pytest.raises(ValueError, match=r"shape \(B, 8\).*got \(8,\)"):
        policy.select_action({STATE_KEY: torch.zeros(8)})
    with pytest.raises(ValueError, match=r"shape \(B, 8\).*got \(2, 7\)"):
        policy.predict_action_chunk({STATE_KEY: torch.zeros(2, 7)})
    with pytest.raises(ValueError, match=r"shape \(B, 8\).*got ndarray"):
        policy.select_action({STATE_KEY: np.zeros((1, 8), dtype=np.float32)})
    with pytest.raises(ValueError, match="floating-point 'observation.state', got torch.int64"):
        policy.select_action({STATE_KEY: torch.zeros(1, 8, dtype=torch.int64)})

    from lerobot.policies.factory import make_policy_config

    wrong_action = make_policy_config(
        "do_nothing", output_features={ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(7,))}
    )
    with pytest.raises(ValueError, match=r"do_nothing needs output 'action' of shape \(8,\), got \(7,\)"):
        DoNothingPolicy(wrong_action)
    no_state = make_policy_config("do_nothing", input_features={})
    with pytest.raises(ValueError, match=r"input 'observation.state' of shape \(8,\), got nothing"):
        DoNothingPolicy(no_state)


def test_holds_the_robot_still_in_bullet_tabletop():
    """Closed loop in the env: the EE stays within a millimetre and a fraction of a degree, the gripper stays open."""
    from lerobot_instant_policy.sim.env import BulletTabletopEnv

    policy, _, _ = make_do_nothing()
    env = BulletTabletopEnv("push_button", observe_pointcloud=False)
    try:
        observation, _ = env.reset(seed=5)
        start = observation["agent_pos"].copy()
        for _ in range(30):
            action = policy.select_action({STATE_KEY: torch.from_numpy(observation["agent_pos"])[None]})[0].numpy()
            observation, _, terminated, _, info = env.step(action)
            assert not terminated and info["is_success"] is False
    finally:
        env.close()
    end = observation["agent_pos"]
    assert np.linalg.norm(end[:3] - start[:3]) < 1e-3
    assert abs(float(np.dot(end[3:7], start[3:7]))) > np.cos(np.radians(0.5) / 2)
    assert end[7] == start[7] == 1.0


def test_save_and_load_round_trip(tmp_path):
    from lerobot.policies.factory import make_pre_post_processors

    policy, preprocessor, postprocessor = make_do_nothing()
    for part in (policy, preprocessor, postprocessor):
        part.save_pretrained(tmp_path / "ckpt")
    loaded = DoNothingPolicy.from_pretrained(tmp_path / "ckpt")
    assert loaded.config.type == "do_nothing" and loaded.config.push_to_hub is False
    loaded_pre, loaded_post = make_pre_post_processors(loaded.config, pretrained_path=str(tmp_path / "ckpt"))
    states = random_states(2, seed=1)
    with torch.inference_mode():
        action = loaded_post(loaded.select_action(loaded_pre({STATE_KEY: states, POINTCLOUD_KEY: torch.zeros(2, 2048, 3)})))
    torch.testing.assert_close(action, states, rtol=0, atol=0)


def test_eval_suite_command_has_no_demonstration_flags(tmp_path):
    command = suite.lerobot_eval_command(
        suite.SuiteSettings(policy="do_nothing"), "push_button", tmp_path / "demos", 1000, tmp_path / "run"
    )
    assert "--policy.type=do_nothing" in command and "--env.task=push_button" in command
    assert not any(part.startswith(("--policy.demo_", "--policy.num_demos")) for part in command)


@pytest.mark.slow  # CI: the suite's lerobot-eval run is tested through make demo's path (test_eval_suite.py)
def test_eval_suite_runs_lerobot_eval_without_recording_demonstrations(tmp_path, capsys):
    """The real ``lerobot-eval --policy.type=do_nothing`` on push_button (1 episode of 80 steps): no success."""
    code = eval_suite.main(
        ["--policy", "do_nothing", "--tasks", "push_button", "--episodes", "1", "--demo-sets", "1", "--batch-size", "1",
         "--out", str(tmp_path)]
    )
    output = capsys.readouterr()
    assert code == 0, output.err
    info = json.loads((tmp_path / "runs" / "do_nothing" / "push_button" / "set-0" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1 and info["overall"]["pc_success"] == 0.0
    assert [entry["task_group"] for entry in info["per_task"]] == ["push_button"]
    assert info["per_task"][0]["metrics"]["successes"] == [False]
    assert not (tmp_path / "demos").exists()
    table = json.loads((tmp_path / "success_table_do_nothing.json").read_text())
    (row,) = table["rows"]
    assert {key: row[key] for key in ("task", "policy", "episodes", "successes", "success_rate", "ci95_low")} == {
        "task": "push_button", "policy": "do_nothing", "episodes": 1, "successes": 0, "success_rate": 0.0,
        "ci95_low": 0.0}
