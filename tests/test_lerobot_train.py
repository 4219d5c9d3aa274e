"""``lerobot-train --policy.type=instant_policy`` end to end (issue 5, "Done when"): 20 steps of the small preset on
CPU on a dataset the test writes, a checkpoint, ``--resume=true`` continuing from it, and ``from_pretrained`` on the
checkpoint predicting actions."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from synthetic_demos import NUM_FRAMES, make_demonstration, object_pose, write_demo_dataset

from lerobot_instant_policy.contract import POINTCLOUD_KEY, STATE_KEY

REPO = "local/ip_train_small"
TRAIN = Path(sys.executable).parent / "lerobot-train"


def run_train(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"}
    result = subprocess.run([str(TRAIN), *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-6000:]
    return result


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Train 20 steps (checkpoints at 10 and 20), then resume to 22 steps; returns the output directory."""
    base = tmp_path_factory.mktemp("ip_train")
    episodes = [("lift", object_pose(0.5, 0.0, 0.0)), ("lift", object_pose(0.45, 0.1, 20.0)),
                ("push", object_pose(0.55, -0.1, -40.0)), ("push", object_pose(0.4, 0.15, 55.0))]
    write_demo_dataset(base / "data", REPO, episodes)
    out = base / "out"
    first = run_train(
        ["--policy.type=instant_policy", "--policy.preset=small", f"--dataset.repo_id={REPO}",
         f"--dataset.root={base / 'data'}", "--steps=20", "--batch_size=2", "--policy.device=cpu",
         f"--output_dir={out}", "--save_freq=10", "--log_freq=10", "--wandb.enable=false", "--num_workers=0"],
        base,
    )
    config_path = out / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    resumed = run_train([f"--config_path={config_path}", "--resume=true", "--steps=22"], base)
    return out, first.stdout + first.stderr, resumed.stdout + resumed.stderr


def test_train_writes_checkpoints_and_resume_continues(trained):
    out, first_log, resumed_log = trained
    checkpoints = out / "checkpoints"
    assert {"000010", "000020", "000022"} <= {path.name for path in checkpoints.iterdir()}
    assert json.loads((checkpoints / "last" / "training_state" / "training_step.json").read_text())["step"] == 22
    assert "step:20" in first_log and "loss:" in first_log
    # the fused AdamW preset is saved by name and parsed again on resume
    train_config = json.loads((checkpoints / "last" / "pretrained_model" / "train_config.json").read_text())
    assert train_config["optimizer"]["type"] == "instant_policy_adamw"
    assert "Resume" in resumed_log or "resum" in resumed_log.lower()
    # a healthy install prints no traceback (LeRobot's torchcodec probe is one line without a system FFmpeg)
    assert "Traceback" not in first_log and "Traceback" not in resumed_log
    saved = json.loads((checkpoints / "000020" / "pretrained_model" / "config.json").read_text())
    assert saved["type"] == "instant_policy" and saved["hidden_dim"] == 128 and saved["push_to_hub"] is False
    # the resumed run started from the step-20 weights: they differ from the step-22 ones but share every key
    from safetensors.torch import load_file

    at_20 = load_file(checkpoints / "000020" / "pretrained_model" / "model.safetensors")
    at_22 = load_file(checkpoints / "000022" / "pretrained_model" / "model.safetensors")
    assert at_20.keys() == at_22.keys()
    assert any(not torch.equal(at_20[key], at_22[key]) for key in at_20)
    assert not any("bank" in key for key in at_20)
    # the frozen encoder's output for every frame was cached beside the dataset once; the resumed run reused it
    (cache,) = (out.parent / "data" / "instant_policy_encodings").iterdir()
    assert json.loads((cache / "meta.json").read_text())["dataset"]["total_frames"] == 4 * NUM_FRAMES
    assert first_log.count("encoding every frame") == 1 and "encoding every frame" not in resumed_log


def test_from_pretrained_on_the_checkpoint_predicts_actions(trained):
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    out, _, _ = trained
    policy = InstantPolicyPolicy.from_pretrained(out / "checkpoints" / "last" / "pretrained_model")
    assert not policy.training and policy.config.preset == "small"
    lifts = [make_demonstration(object_pose(0.5, 0.0, 0.0), "lift", seed=0),
             make_demonstration(object_pose(0.45, 0.1, 20.0), "lift", seed=1)]
    policy.set_demonstrations(lifts)
    live = make_demonstration(object_pose(0.52, -0.05, 35.0), "lift", seed=7)
    batch = {POINTCLOUD_KEY: torch.from_numpy(live.points_world[:1]), STATE_KEY: torch.from_numpy(live.state[:1]),
             "task": ["lift"]}
    chunk = policy.predict_action_chunk(batch)
    assert chunk.shape == (1, 8, 8) and torch.isfinite(chunk).all()
    action = policy.select_action(batch)
    assert action.shape == (1, 8) and torch.isfinite(action).all()
