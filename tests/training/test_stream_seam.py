"""``lerobot-ip-train``: LeRobot's own ``lerobot-train`` (0.6.1, pinned) on the pseudo-task stream, through the two
names ``training.stream_seam`` replaces. Each run is a child process, as a user runs it: LeRobot's loop, its checkpoints
(loadable with ``from_pretrained``), its resume (the stream starts past the checkpoint's tasks), its refusal of flags
the stream sets; and two processes under ``accelerate launch``, each with its own stream."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors import safe_open

from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.training.stream_seam import (
    POOL_STATE_FILE,
    RESUME_TASKS_PER_SAMPLE,
    pool_start_task,
    resume_start_task,
)
from lerobot_instant_policy.training.weight_average import AVERAGE_FILE, write_averaged_model

BIN = Path(sys.executable).parent
# Two objects and one task group: every task loads the same two meshes.
STREAM_CONFIG = {"seed": 5, "object_pool": ["pb/cube", "pb/duck"], "family": "full", "tasks_per_object_group": 1}
POLICY_FLAGS = ["--policy.type=instant_policy", "--policy.device=cpu", "--policy.push_to_hub=false",
                "--policy.max_demos=2", "--policy.reencode_action_clouds=false", "--num_workers=0", "--batch_size=2",
                "--log_freq=1", "--save_freq=2"]


def _config_file(tmp_path: Path) -> Path:
    path = tmp_path / "stream.json"
    path.write_text(json.dumps(STREAM_CONFIG))
    return path


def _train(tmp_path: Path, *flags: str, command: tuple[str, ...] = (str(BIN / "lerobot-ip-train"),),
           timeout: int = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    return subprocess.run([*command, f"--stream.config={_config_file(tmp_path)}", "--stream.samples_per_task=2",
                           "--stream.tasks_per_render=1", *flags], capture_output=True, text=True, timeout=timeout, env=env, cwd=tmp_path)


def test_lerobot_train_trains_on_the_stream_saves_loadable_checkpoints_and_resumes_past_its_tasks(tmp_path):
    out = tmp_path / "run"
    run = _train(tmp_path, *POLICY_FLAGS, "--steps=2", f"--output_dir={out}")
    assert run.returncode == 0, run.stderr[-3000:]
    log = run.stdout + run.stderr
    assert "training on the pseudo-task stream from task 0 (process 0 of 1)" in log
    assert "step:2" in log.replace(" ", "") and "loss:" in log
    checkpoint = out / "checkpoints" / "000002" / "pretrained_model"
    policy = InstantPolicyPolicy.from_pretrained(checkpoint)
    assert policy.config.max_demos == 2 and all(torch.isfinite(p).all() for p in policy.parameters())
    train_config = json.loads((checkpoint / "train_config.json").read_text())
    assert train_config["dataset"]["streaming"] is True
    record = json.loads((out / "stream" / "process-0-from-task-0.json").read_text())
    assert record["config"]["generation"]["object_pool"] == STREAM_CONFIG["object_pool"]
    assert record["config"]["num_demos"] == 2 and record["config"]["samples_per_task"] == 2

    resumed = _train(tmp_path, f"--config_path={checkpoint / 'train_config.json'}", "--resume=true", "--steps=3")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    start = 2 * 2 * 1 * RESUME_TASKS_PER_SAMPLE  # step 2, batch 2, one process
    assert f"from task {start} (process 0 of 1)" in resumed.stdout + resumed.stderr
    assert (out / "checkpoints" / "000003" / "pretrained_model" / "model.safetensors").is_file()
    assert resume_start_task(out / "checkpoints" / "000002", batch_size=2, world_size=1) == start


def test_the_task_pool_trains_records_its_state_in_each_save_and_a_killed_run_resumes_past_its_tasks(tmp_path,
                                                                                                     pool_run):
    """``--pool``: every save carries the pool's account; a run killed after its first save resumes from that save,
    its pool starting past every task the save's run had received (nothing seen before is drawn again). With
    ``--average.decay`` every save also carries the weights' moving average, which the resumed run goes on with,
    at the saved decay, without being told again. The run is the session's ``pool_run`` (4 steps, a save every 2)."""
    assert "training on the pseudo-task pool from task 0 (process 0 of 1)" in (pool_run / "train.log").read_text()
    states = {step: json.loads((pool_run / "run" / "checkpoints" / f"{step:06d}" / "training_state" /
                                POOL_STATE_FILE).read_text()) for step in (2, 4)}
    for step, state in states.items():
        stats = state["stats"]
        assert stats["samples"] == 2 * step and stats["distinct_tasks_used"] <= stats["tasks_received"]
        assert stats["next_task"] >= stats["tasks_received"] + stats["skipped"] and stats["max_uses"] >= 1
    out = tmp_path / "run"  # killed before its second save
    shutil.copytree(pool_run / "run", out, symlinks=True, ignore=shutil.ignore_patterns("000004"))
    first_save = out / "checkpoints" / "000002"
    resumed = _train(tmp_path, "--pool", "--pool.min_tasks=1", "--pool.capacity=4",
                     f"--config_path={first_save / 'pretrained_model' / 'train_config.json'}", "--resume=true",
                     f"--output_dir={out}", "--steps=3")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    next_task = states[2]["stats"]["next_task"]
    assert f"training on the pseudo-task pool from task {next_task} (process 0 of 1)" in resumed.stdout + resumed.stderr
    state = json.loads((out / "checkpoints" / "000003" / "training_state" / POOL_STATE_FILE).read_text())
    assert state["start_task"] == next_task and state["stats"]["samples"] == 2  # one step past the save
    assert pool_start_task(first_save, batch_size=2, world_size=1) == next_task

    for step, updates in ((2, 2), (3, 3)):  # the resumed average went on from the save's, one update a step
        with safe_open(str(out / "checkpoints" / f"{step:06d}" / "training_state" / AVERAGE_FILE), "pt") as handle:
            assert handle.metadata() == {"decay": "0.5", "updates": str(updates)}
    raw = InstantPolicyPolicy.from_pretrained(out / "checkpoints" / "000003" / "pretrained_model")
    averaged = InstantPolicyPolicy.from_pretrained(write_averaged_model(out / "checkpoints" / "000003",
                                                                       tmp_path / "average"))
    trained = {name for name, parameter in raw.named_parameters() if parameter.requires_grad}
    raw_tensors, averaged_tensors = raw.state_dict(), averaged.state_dict()
    assert any(not torch.equal(raw_tensors[name], averaged_tensors[name]) for name in trained)
    assert all(torch.equal(raw_tensors[name], averaged_tensors[name]) for name in raw_tensors if name not in trained)


def test_flags_the_stream_sets_are_refused_and_a_missing_config_is_named(tmp_path, capsys):
    """Refused before LeRobot is entered: nothing is patched, nothing written."""
    from lerobot_instant_policy.cli.train_stream import main

    config = f"--stream.config={_config_file(tmp_path)}"
    assert main([config, *POLICY_FLAGS, "--dataset.repo_id=lerobot/pusht", f"--output_dir={tmp_path / 'x'}"]) == 2
    assert "--dataset.repo_id is set by the stream; leave it out" in capsys.readouterr().err
    assert main(["--stream.config=nowhere.json", *POLICY_FLAGS]) == 2
    assert "nowhere.json" in capsys.readouterr().err
    assert main([config, "--stream.samples_per_task=0", *POLICY_FLAGS]) == 2
    assert "samples_per_task must be a positive integer" in capsys.readouterr().err
    assert main([config, "--stream.wrong_prior_keep=1.5", *POLICY_FLAGS]) == 2
    assert "wrong_prior_keep must lie in [0, 1]" in capsys.readouterr().err
    assert main([config, "--stream.prior_time_shift=-2", *POLICY_FLAGS]) == 2
    assert "prior_time_shift must be a non-negative integer" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_two_processes_under_accelerate_each_draw_their_own_stream(tmp_path):
    out = tmp_path / "run"
    """Launched as ``accelerate launch --multi_gpu`` launches on GPUs (torch's ``torchrun``), here two CPU processes:
    LeRobot's loop sees a world of two, and each process streams its own task indices."""
    out = tmp_path / "run"
    command = (str(BIN / "torchrun"), "--nproc_per_node=2", "-m", "lerobot_instant_policy.cli.train_stream")
    run = _train(tmp_path, *POLICY_FLAGS, "--steps=2", f"--output_dir={out}", command=command, timeout=900)
    log = run.stdout + run.stderr
    assert run.returncode == 0, log[-3000:]
    assert "Effective batch size: 2 x 2 = 4" in log
    records = [json.loads((out / "stream" / f"process-{rank}-from-task-0.json").read_text()) for rank in (0, 1)]
    assert [(record["rank"], record["world_size"]) for record in records] == [(0, 2), (1, 2)]
    assert records[0]["config"] == records[1]["config"]
    assert (out / "checkpoints" / "000002" / "pretrained_model" / "model.safetensors").is_file()
