"""The instant_policy checkpoint shipped in the package (issue 6): complete, small, loadable the way LeRobot loads
it, better than an untrained network on held-out pseudo-tasks (``make demo``'s run of it through ``lerobot-eval``:
test_eval_suite.py)."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from lerobot_instant_policy.cli.generate import main as generate_main
from lerobot_instant_policy.configuration_instant_policy import (
    SHIPPED_CHECKPOINT,
    SHIPPED_REPLAY_PRIOR_CHECKPOINT,
    InstantPolicyConfig,
)
from lerobot_instant_policy.evaluation.checkpoints import Checkpoint, load_checkpoint
from lerobot_instant_policy.evaluation.loss_curve import evaluate_loss, load_evaluation_set
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

SHIPPED = SHIPPED_CHECKPOINT
MAX_BYTES = 50 * 1024**2

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def test_the_checkpoint_is_complete_small_and_documented():
    names = {path.name for path in SHIPPED.iterdir()}
    expected = {"config.json", "model.safetensors", "train_config.json", "README.md",
                "policy_preprocessor.json", "policy_postprocessor.json"}
    assert expected <= names, f"missing from {SHIPPED}: {sorted(expected - names)}"
    assert sum(path.stat().st_size for path in SHIPPED.rglob("*") if path.is_file()) <= MAX_BYTES
    config = json.loads((SHIPPED / "config.json").read_text())
    assert config["type"] == "instant_policy"
    assert config["demo_root"] is None and config["encoder_weights"] is None  # nothing machine-specific to load
    card = (SHIPPED / "README.md").read_text()
    for fact in ("pseudo-demonstrations", "## Data", "## Training", "steps", "CPU", "## Results"):
        assert fact in card, f"the model card does not state {fact!r}"


def test_the_replay_prior_checkpoint_is_the_shipped_weights_run_from_the_replay():
    """``instant_policy_replay_prior``: the shipped network with the option's inference settings in its config, so that
    ``--policy.path`` alone runs it from the per-object replay (``make demo`` runs it through ``lerobot-eval``:
    test_eval_suite.py). Its card says its weights are the faithful checkpoint's: a new faithful checkpoint must
    bring its own measured replay-prior one or say otherwise."""
    names = {path.name for path in SHIPPED_REPLAY_PRIOR_CHECKPOINT.iterdir()}
    assert names == {path.name for path in SHIPPED.iterdir()}
    assert (SHIPPED_REPLAY_PRIOR_CHECKPOINT / "model.safetensors").read_bytes() == (
        SHIPPED / "model.safetensors").read_bytes()
    option, faithful = (InstantPolicyConfig.from_pretrained(path) for path in (SHIPPED_REPLAY_PRIOR_CHECKPOINT, SHIPPED))
    assert (option.replay_init_strength, option.inference_steps, option.replay_per_object) == (0.125, 8, True)
    assert (faithful.replay_init_strength, faithful.replay_per_object) == (None, False)
    differing = {field.name for field in dataclasses.fields(option)
                 if getattr(option, field.name) != getattr(faithful, field.name)}
    assert differing == {"replay_init_strength", "inference_steps", "replay_per_object"}
    card = (SHIPPED_REPLAY_PRIOR_CHECKPOINT / "README.md").read_text()
    for fact in ("replay_init_strength", "## When to use it", "## Results", "test split", "MT10"):
        assert fact in card, f"the model card does not state {fact!r}"


@pytest.mark.slow  # CI: the paths it runs are tested elsewhere; kept out of the 10-minute suite
def test_the_shipped_model_beats_an_untrained_one_on_held_out_pseudo_tasks(tmp_path):
    """Its training loss on pseudo-tasks made of held-out objects, with the same draws of noise and context, is far
    below that of the same network freshly initialised (the frozen encoder is the same in both)."""
    assert generate_main(["--out", str(tmp_path / "val"), "--repo-id", "local/val", "--num-tasks", "2",
                          "--demos-per-task", "3", "--seed", "7", "--object-split", "held_out", "--workers", "1",
                          "--no-progress"]) == 0
    shipped, preprocessor = load_checkpoint(Checkpoint(step=0, path=SHIPPED))
    evaluation = load_evaluation_set("val", tmp_path / "val", shipped.config, samples=48, seed=0)
    trained = evaluate_loss(shipped, preprocessor, evaluation, batch_size=16, seed=0)
    torch.manual_seed(0)
    untrained = InstantPolicyPolicy(dataclasses.replace(shipped.config)).eval()
    fresh = evaluate_loss(untrained, preprocessor, evaluation, batch_size=16, seed=0)
    assert trained.loss < 0.6 * fresh.loss, (trained, fresh)


def test_the_shipped_model_reads_its_demonstrations_on_held_out_pseudo_tasks(held_out_pseudo_tasks, capsys):
    """On fresh pseudo-tasks of the full generator (held-out objects, the curriculum's bounded turns and one layout per
    task: conftest's ``held_out_pseudo_tasks``, 4 tasks of one object pair, 8 frames of each live episode), its actions
    follow its own demonstrations much better than another task's relabelled as its own (context gain in translation;
    a network that ignores them scores about 1) and better than holding still."""
    from lerobot_instant_policy.cli.action_error import main as action_error_main

    capsys.readouterr()
    assert action_error_main(["--policy-path", str(SHIPPED), "--root", str(held_out_pseudo_tasks), "--tasks", "4",
                              "--frames-per-task", "8", "--K", "4", "--N", "2", "--L", "10", "--no-untrained",
                              "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    own = result["settings"][0]["translation_mm"]
    assert result["tasks"] == 4 and result["frames"] == 32, result
    assert result["context_gain"]["translation"] > 1.3, result
    assert own < 0.85 * result["hold"]["translation_mm"], result


def test_bench_times_the_shipped_checkpoint_with_its_own_settings():
    from lerobot_instant_policy.benchmarks.policy import bench_inference

    result = bench_inference(policy_path=str(SHIPPED), repeats=1)
    config = InstantPolicyConfig.from_pretrained(SHIPPED)
    assert result["checkpoint"] == str(SHIPPED)
    assert (result["K"], result["T"], result["reencode_action_clouds"]) == (
        config.inference_steps, config.horizon, config.reencode_action_clouds)
    assert result["ms_per_control_step"] > 0 and result["parameters"] > 1_000_000
