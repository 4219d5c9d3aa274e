"""The training curve (issue 6): each checkpoint's loss on fixed, seeded frames of the training data and of held-out
pseudo-tasks, ``lerobot-ip-loss-curve``'s JSON cache and PNG, and its errors. The checkpoints come from a real
2-step ``lerobot-train`` run (LeRobot's ``train``, in this process) on a pseudo-demonstration dataset made by
``lerobot-ip-generate``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import torch
from synthetic_demos import object_pose, write_demo_dataset

from lerobot_instant_policy.cli.generate import main as generate_main
from lerobot_instant_policy.cli.loss_curve import main as loss_curve_main
from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.evaluation.checkpoints import EvaluationError, find_checkpoints, load_checkpoint
from lerobot_instant_policy.evaluation.loss_curve import (
    LossCurveCache,
    LossEstimate,
    evaluate_loss,
    load_evaluation_set,
    prior_only_loss,
)
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.processor_instant_policy import make_instant_policy_pre_post_processors

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def train_in_this_process(args: list[str], cwd: Path) -> None:
    """``lerobot-train ARGS`` as LeRobot's own ``train`` in this process: the checkpoints are the same, without a
    second interpreter importing LeRobot (the ``lerobot-train`` command itself runs in test_lerobot_train.py). What
    it sets for the whole process is put back: the root logger's handlers and level, and accelerate's state."""
    import logging
    import sys

    from accelerate.state import AcceleratorState
    from lerobot.scripts.lerobot_train import train

    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(sys, "argv", ["lerobot-train", *args])
            patch.chdir(cwd)
            patch.setenv("WANDB_MODE", "disabled")
            train()
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
        AcceleratorState._reset_state(reset_partial_state=True)


@pytest.fixture(scope="module")
def run(tmp_path_factory, single_torch_thread):
    """``(base, run_dir)``: pseudo-demos at ``base/train`` (2 tasks × 2 demos, training objects) and ``base/val``
    (2 tasks × 2 demos, held-out objects), and a lerobot-train run with checkpoints after steps 1 and 2. Reach
    pseudo-tasks, the ladder's shortest (about 50 frames an episode here, 85 and 144 with the full generator):
    training and the first evaluation on a dataset encode all its frames; the curve's machinery is alike on any."""
    base = tmp_path_factory.mktemp("loss_curve")
    common = ["--demos-per-task", "2", "--family", "reach", "--workers", "1", "--no-progress"]
    assert generate_main(["--out", str(base / "train"), "--repo-id", "local/train", "--num-tasks", "2", "--seed", "0",
                          *common]) == 0
    assert generate_main(["--out", str(base / "val"), "--repo-id", "local/val", "--num-tasks", "2", "--seed", "1",
                          "--object-split", "held_out", *common]) == 0
    train_in_this_process(["--policy.type=instant_policy", "--policy.preset=small", "--dataset.repo_id=local/train",
                           f"--dataset.root={base / 'train'}", "--steps=2", "--batch_size=2", "--policy.device=cpu",
                           f"--output_dir={base / 'run'}", "--save_freq=1", "--log_freq=1", "--wandb.enable=false",
                           "--num_workers=0"], base)
    return base, base / "run"


def curve_cli(base: Path, run_dir: Path, capsys, *extra: str) -> tuple[int, dict | None, str]:
    """Run ``lerobot-ip-loss-curve`` on 8 frames per dataset; returns the exit code, the summary and stderr."""
    code = loss_curve_main(["--run", str(run_dir), "--train-root", str(base / "train"), "--val-root", str(base / "val"),
                            "--samples", "8", "--batch-size", "4", "--out", str(base / "curve.png"), *extra])
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else None), captured.err


def test_checkpoint_loss_is_deterministic_and_compares_checkpoints_on_the_same_draws(run):
    base, run_dir = run
    checkpoints = find_checkpoints(run_dir)
    assert [checkpoint.step for checkpoint in checkpoints] == [1, 2]  # the "last" link is skipped
    first, preprocessor = load_checkpoint(checkpoints[0])
    second, _ = load_checkpoint(checkpoints[1])
    evaluation = load_evaluation_set("train", base / "train", first.config, samples=8, seed=0)
    rng_state = torch.get_rng_state()
    once = evaluate_loss(first, preprocessor, evaluation, batch_size=4, seed=0)
    again = evaluate_loss(first, preprocessor, evaluation, batch_size=4, seed=0)
    assert once == again and once.samples == 8
    assert torch.equal(torch.get_rng_state(), rng_state), "evaluation must not move the caller's RNG"
    weight = first.config.gripper_loss_weight
    assert once.loss == pytest.approx(once.translation + once.rotation + weight * once.gripper, rel=1e-5)
    assert min(once.translation, once.rotation, once.gripper) > 0
    # other weights or other noise give other numbers
    assert evaluate_loss(second, preprocessor, evaluation, batch_size=4, seed=0).loss != once.loss
    assert evaluate_loss(first, preprocessor, evaluation, batch_size=4, seed=1).loss != once.loss
    # the context swap: the same frames and draws with another task's demonstrations give another loss
    val = load_evaluation_set("val", base / "val", first.config, samples=8, seed=0)
    own = evaluate_loss(first, preprocessor, val, batch_size=4, seed=0)
    swapped = evaluate_loss(first, preprocessor, val, batch_size=4, seed=0, swap_context=True)
    assert swapped.samples == own.samples == 8 and swapped.translation != own.translation
    assert evaluate_loss(first, preprocessor, val, batch_size=4, seed=0) == own  # the swap left the bank as it was
    # the prior-only level is a property of the data and the diffusion, not of the weights
    prior = prior_only_loss(first, preprocessor, val, batch_size=4, seed=0)
    assert prior == prior_only_loss(second, preprocessor, val, batch_size=4, seed=0)
    assert prior["samples"] == 8 and prior["translation"] > 0 and prior["rotation"] > 0
    # the same seed draws the same frames
    assert np.array_equal(evaluation.indices, load_evaluation_set("t", base / "train", first.config, 8, 0).indices)


def test_cli_draws_the_png_and_only_evaluates_new_checkpoints(run, capsys):
    base, run_dir = run
    code, summary, err = curve_cli(base, run_dir, capsys)
    assert code == 0, err
    assert summary["evaluated"] == [1, 2] and summary["reused"] == []
    assert summary["datasets"]["train"]["episodes"] == 4 and summary["datasets"]["val"]["tasks"] == 2
    assert summary["prior_only_val"]["translation"] > 0
    assert all(point["context_gain_translation"] > 0 for point in summary["curve"])
    picture = matplotlib.image.imread(summary["png"])
    assert picture.ndim == 3 and picture.shape[0] > 300 and picture.shape[1] > 600
    stored = json.loads((base / "curve.json").read_text())
    assert [entry["step"] for entry in stored["checkpoints"]] == [1, 2]
    for entry in stored["checkpoints"]:
        for name in ("train", "val", "val_swap"):
            assert entry[name]["samples"] == 8 and np.isfinite(entry[name]["loss"]) and entry[name]["loss"] > 0

    code, cached, _ = curve_cli(base, run_dir, capsys)
    assert code == 0 and cached["evaluated"] == [] and cached["reused"] == [1, 2]
    assert cached["curve"] == summary["curve"]

    # a new checkpoint (a copy of step 2's weights) is the only one evaluated, and scores exactly as step 2
    shutil.copytree(run_dir / "checkpoints" / "000002", run_dir / "checkpoints" / "000003", symlinks=True)
    try:
        code, grown, _ = curve_cli(base, run_dir, capsys)
        assert code == 0 and grown["evaluated"] == [3] and grown["reused"] == [1, 2]
        assert grown["curve"][2]["train_loss"] == grown["curve"][1]["train_loss"]
        assert grown["curve"][2]["val_loss"] == grown["curve"][1]["val_loss"]
    finally:
        shutil.rmtree(run_dir / "checkpoints" / "000003")


def test_cache_is_only_reused_for_the_same_settings_datasets_and_weights(tmp_path):
    datasets = {"train": {"root": "/a", "fingerprint": "f1", "episodes": 4, "tasks": 2, "frames": 400, "samples": 8}}
    settings = {"samples": 8, "batch_size": 4, "seed": 0}
    result = {"train": LossEstimate(loss=1.0, translation=0.5, rotation=0.3, gripper=0.2, samples=8)}
    cache = LossCurveCache(tmp_path / "curve.json", settings, datasets)
    cache.put(10, "w10", result)
    cache.save([10])
    moved = {"train": {**datasets["train"], "root": "/moved"}}
    reopened = LossCurveCache(tmp_path / "curve.json", settings, moved)
    assert reopened.get(10, "w10")["train"]["loss"] == 1.0 and not reopened.discarded
    assert reopened.get(10, "other weights") is None and reopened.get(20, "w10") is None
    regenerated = {"train": {**datasets["train"], "fingerprint": "f2"}}
    for other_settings, other_datasets in (({**settings, "seed": 1}, datasets), ({**settings, "batch_size": 2}, datasets),
                                           (settings, regenerated)):
        stale = LossCurveCache(tmp_path / "curve.json", other_settings, other_datasets)
        assert stale.discarded and stale.get(10, "w10") is None


def test_errors_name_the_problem(run, tmp_path, capsys):
    base, run_dir = run
    code, _, err = curve_cli(base, tmp_path, capsys)
    assert code == 2 and "no checkpoints found" in err

    code = loss_curve_main(["--run", str(run_dir), "--train-root", str(tmp_path / "absent"), "--val-root",
                            str(base / "val"), "--out", str(tmp_path / "x.png")])
    assert code == 2 and "does not exist" in capsys.readouterr().err

    write_demo_dataset(tmp_path / "plain", "local/plain", [("lift", object_pose(0.5, 0.0, 0.0))])
    code = loss_curve_main(["--run", str(run_dir), "--train-root", str(base / "train"), "--val-root",
                            str(tmp_path / "plain"), "--out", str(tmp_path / "x.png")])
    assert code == 2 and "not a pseudo-demonstration dataset" in capsys.readouterr().err

    foreign = tmp_path / "foreign" / "checkpoints" / "000005"
    shutil.copytree(run_dir / "checkpoints" / "000001", foreign)
    config_file = foreign / "pretrained_model" / "config.json"
    config_file.write_text(json.dumps({**json.loads(config_file.read_text()), "type": "act"}))
    code, _, err = curve_cli(base, tmp_path / "foreign", capsys)
    assert code == 2 and "is a 'act' policy, not 'instant_policy'" in err

    config = InstantPolicyConfig(device="cpu")
    with pytest.raises(EvaluationError, match="samples must be at least 1"):
        load_evaluation_set("train", base / "train", config, samples=0, seed=0)
    evaluation = load_evaluation_set("train", base / "train", config, samples=4, seed=0)
    with pytest.raises(EvaluationError, match="batch_size must be at least 1"):
        evaluate_loss(InstantPolicyPolicy(config), None, evaluation, batch_size=0)


def test_training_steps_lower_the_evaluated_loss(run):
    """20 AdamW steps on the sampled frames lower their evaluated loss (to about 0.57 of the initial one here)."""
    base, _ = run
    torch.manual_seed(0)
    config = InstantPolicyConfig(device="cpu", optimizer_lr=1e-3, reencode_action_clouds=False, max_demos=1)
    policy = InstantPolicyPolicy(config)
    preprocessor, _ = make_instant_policy_pre_post_processors(config)
    evaluation = load_evaluation_set("train", base / "train", config, samples=6, seed=0)
    before = evaluate_loss(policy, preprocessor, evaluation, batch_size=6)
    batch = preprocessor(next(iter(torch.utils.data.DataLoader(
        torch.utils.data.Subset(evaluation.dataset, evaluation.indices.tolist()), batch_size=6))))
    optimizer = torch.optim.AdamW(policy.get_optim_params(), lr=config.optimizer_lr)
    policy.train()
    for _ in range(20):
        loss, _ = policy.forward(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    after = evaluate_loss(policy, preprocessor, evaluation, batch_size=6)
    assert policy.training, "evaluate_loss leaves the policy in the mode it found it in"
    assert after.loss < 0.75 * before.loss, (before, after)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cli_runs_on_cuda_and_its_prior_level_is_the_cpu_figure(run, capsys):
    """The prior-only level draws its timesteps and noise on the CPU from the same frames, so a run on the GPU reports
    the CPU's figure (up to float32 kernels); the network's losses draw on the GPU's RNG and only need to be finite."""
    base, run_dir = run
    code, on_cpu, err = curve_cli(base, run_dir, capsys, "--out", str(base / "curve_cpu.png"), "--device", "cpu")
    assert code == 0, err
    code, on_cuda, err = curve_cli(base, run_dir, capsys, "--out", str(base / "curve_cuda.png"), "--device", "cuda")
    assert code == 0, err
    assert on_cuda["prior_only_val"]["translation"] == pytest.approx(on_cpu["prior_only_val"]["translation"], rel=1e-5)
    assert all(point["context_gain_translation"] > 0 for point in on_cuda["curve"])
