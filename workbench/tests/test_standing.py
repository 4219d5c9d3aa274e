"""The standing training run (``workbench.standing``): which save a run continues, which saves count as complete,
the last save always replaced, the best only when it beats the best on both sets, a point on the curve per run (with
the figures' intervals where the run has them), the paired difference from the best recorded where the best's
per-task errors are kept, the comparison with the shipped checkpoint (validated once, cached) deciding whether step 5
is due, a device's packed save kept the same way, what the curve predicts, and bad settings refused."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path

import pytest
import torch

import workbench.standing as standing_module
from lerobot_instant_policy.evaluation.action_error import task_intervals
from lerobot_instant_policy.evaluation.manifest import checkpoint_fingerprint
from lerobot_instant_policy.replay.timing import TIMING_MODEL
from workbench.standing import (
    RECORD,
    SHIPPED_RECORD,
    StandingConfig,
    StandingError,
    accept,
    complete_saves,
    figures,
    json_result,
    keep,
    pack,
    paired_against,
    per_task,
    plot_curve,
    read_record,
    shipped_validation,
    start_save,
    train_command,
    trend,
    validation_record,
)

HOLD_MM = [25.0, 30.0, 35.0, 28.0, 32.0, 30.0]


def _action_error(value: float) -> dict:
    """A ``lerobot-ip-action-error`` result of 6 tasks × 4 frames, ``value`` times holding still's error on each task
    (a spread of ±5% about it), the swap 1.3 times its own."""
    own = [value * hold * (1 + 0.05 * (-1) ** index) for index, hold in enumerate(HOLD_MM)]
    rows = [{"task": f"pseudo-s124-{index:06d}", "frames": 4, "own_mm": round(o, 3), "hold_mm": h,
             "swap_mm": round(1.3 * o, 3)} for index, (o, h) in enumerate(zip(own, HOLD_MM))]
    mean = sum(own) / len(own)
    return {"seed": 0, "frames_per_task": 4, "horizon_T": 8, "tasks": 6,
            "settings": [{"K": 4, "N": 2, "L": 10, "translation_mm": round(mean, 3)}],
            "hold": {"translation_mm": round(sum(HOLD_MM) / 6, 3)}, "context_gain": {"translation": 1.3},
            "per_task": rows, "intervals": task_intervals(rows)}


def _entry(moved: float, one_layout: float, samples_total: int, per_task_kept: bool = False) -> dict:
    """A run's record; with ``per_task_kept`` as a run validated now writes it (figures with their intervals, the
    per-task errors), else as runs did before the intervals were kept."""
    def old_figures(value):
        return {"translation_mm": 30 * value, "hold_translation_mm": 30.0, "vs_holding_still": value,
                "context_gain": 1.3}

    results = {"moved": _action_error(moved), "one_layout": _action_error(one_layout)}
    entry = {"samples_total": samples_total, "tasks_total": samples_total // 30, "hidden_dim": 128, "device": "cpu",
             "start_step": 0, "end_step": samples_total // 8, "started": "2026-11-27T00:00:00+00:00",
             "config": {"val_tasks": 24, "val_frames_per_task": 4}}
    if per_task_kept:
        return {**entry, **validation_record(results)}
    return {**entry, "validation": {"moved": old_figures(moved), "one_layout": old_figures(one_layout)}}


def _save(root: Path, step: int, entries: list[dict] | None = None, complete: bool = True) -> Path:
    """A LeRobot step checkpoint of a pool run: weights, training state, the pool's state when complete."""
    save = root / "checkpoints" / f"{step:06d}"
    (save / "pretrained_model").mkdir(parents=True)
    (save / "pretrained_model" / "model.safetensors").write_text(f"weights {step}")
    (save / "training_state").mkdir()
    (save / "training_state" / "training_step.json").write_text(json.dumps({"step": step}))
    if complete:
        (save / "training_state" / "task_pool.json").write_text(json.dumps({"start_task": 0, "stats": {}}))
    if entries is not None:
        (save / RECORD).write_text(json.dumps({"runs": entries}))
    return save


def test_only_saves_written_to_the_end_count_and_the_last_one_is_continued(tmp_path):
    run = tmp_path / "run"
    _save(run, 500)
    _save(run, 1000)
    _save(run, 1500, complete=False)  # killed while saving: no pool state yet
    assert [save.name for save in complete_saves(run)] == ["000500", "001000"]
    standing = tmp_path / "standing"
    assert start_save(StandingConfig(), standing) is None  # the shipped checkpoint, a fresh optimizer
    assert start_save(StandingConfig(start=str(run / "checkpoints" / "001000")), standing) == run / "checkpoints" / "001000"
    with pytest.raises(ValueError, match="LeRobot step checkpoint"):
        start_save(StandingConfig(start=str(tmp_path)), standing)
    keep(_save(run, 2000, [_entry(0.9, 0.6, 800)]), standing, tmp_path / "curve.json")
    assert start_save(StandingConfig(start=str(run / "checkpoints" / "001000")), standing) == standing / "last"


def test_the_last_save_is_always_replaced_and_the_best_only_when_better_on_both_sets(tmp_path):
    run, standing, curve = tmp_path / "run", tmp_path / "standing", tmp_path / "curve.json"
    first = keep(_save(run, 100, [_entry(0.9, 0.6, 800)]), standing, curve)
    assert first["best"] and (standing / "best" / "pretrained_model" / "model.safetensors").read_text() == "weights 100"
    worse = keep(_save(run, 200, [_entry(0.95, 0.5, 1600)]), standing, curve)  # worse on moved objects
    assert not worse["best"]
    assert (standing / "last" / "pretrained_model" / "model.safetensors").read_text() == "weights 200"
    assert (standing / "last" / "training_state" / "training_step.json").is_file()
    assert (standing / "best" / "pretrained_model" / "model.safetensors").read_text() == "weights 100"
    better = keep(_save(run, 300, [_entry(0.85, 0.55, 2400)]), standing, curve)
    assert better["best"] and read_record(standing / "best")["runs"][-1]["samples_total"] == 2400
    assert not (standing / ".last-new").exists()
    points = json.loads(curve.read_text())["points"]
    assert [point["samples_total"] for point in points] == [800, 1600, 2400]
    assert [point["kept"] for point in points] == [True, False, True]
    assert points[1]["moved_vs_holding_still"] == 0.95 and "step 0 to 200" in points[1]["source"]
    assert curve.with_suffix(".png").stat().st_size > 10_000  # the picture is redrawn beside the JSON


def test_a_save_brought_back_from_a_device_is_kept_like_a_local_one(tmp_path, monkeypatch):
    monkeypatch.setattr(standing_module, "validate", lambda *args: pytest.fail("compared on the device already"))
    save = _save(tmp_path / "device", 700, [_compared(0.8, 0.5, 5600, _shipped(0.9, 0.6))])
    pack(save, tmp_path / "out")
    result = accept(tmp_path / "out", tmp_path / "standing", tmp_path / "curve.json")
    assert result["best"] and result["point"]["samples_total"] == 5600
    assert (tmp_path / "standing" / "last" / "pretrained_model" / "model.safetensors").read_text() == "weights 700"


def test_a_run_resumes_its_save_and_a_first_run_continues_the_shipped_weights(tmp_path):
    config = StandingConfig(device="cpu", generators=2, samples_per_task=8, batch_size=64)
    resumed = train_command(config, tmp_path / "000500", tmp_path / "run")
    assert "--batch_size=64" in resumed  # not the saved config's batch: the samples a run counts are steps × this
    assert "--resume=true" in resumed and f"--config_path={tmp_path / '000500' / 'pretrained_model'}/train_config.json" \
        in resumed
    assert "--pool" in resumed and "--pool.generators=2" in resumed and "--stream.samples_per_task=8" in resumed
    assert "--optimizer.moment_rebuild_steps=100" in resumed  # a compact save's moments, rebuilt first
    fresh = train_command(config, None, tmp_path / "run")
    assert any(arg.startswith("--policy.path=") for arg in fresh) and "--resume=true" not in fresh
    assert "--pool.device=cpu" in fresh and "--policy.device=cpu" in fresh
    on_gpu = train_command(StandingConfig(device="cuda", generator_device="cpu"), None, tmp_path / "run")
    assert "--pool.device=cpu" in on_gpu and "--policy.device=cuda" in on_gpu  # the CPU cores feed the GPU's update


@pytest.mark.parametrize(("overrides", "message"), [
    ({"deadline_s": 100.0, "validate_s": 200.0}, "validate_s must lie in"),
    ({"generators": 0}, "generators must be positive"),
    ({"optimizer_lr": 0.0}, "optimizer_lr must be positive"),
])
def test_bad_settings_are_refused(overrides, message):
    with pytest.raises(ValueError, match=message):
        StandingConfig(**overrides).validate()


def test_the_command_line_refuses_bad_settings_and_writes_nothing(tmp_path, capsys):
    from workbench.cli.standing import main

    assert main(["--standing", str(tmp_path / "s"), "run", "--deadline-s", "10", "--validate-s", "20"]) == 2
    assert "validate_s must lie in" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_the_json_result_is_found_after_other_output():
    assert json_result('loading {x}\n{\n  "a": 1\n}\n') == {"a": 1}
    with pytest.raises(StandingError, match="no JSON result"):
        json_result("nothing here")


def test_a_run_validates_from_the_replay_it_is_told_and_keys_its_cache_by_it(tmp_path, monkeypatch):
    """``run`` / ``conclude`` take the replay start as ``compare`` does: its strength and plan reach every
    ``lerobot-ip-action-error`` call, and a result validated another way (another replay, or priors read with another
    timing) is not read back for it."""
    from workbench.cli.standing import build_parser, replay_options

    args = build_parser().parse_args(["run", "--replay-init-strength", "0.25", "--replay-anchored", "true"])
    config = StandingConfig(**replay_options(args))
    assert (config.replay_init_strength, config.replay_per_object, config.replay_anchored) == (0.25, None, True)
    commands = []

    def refuse(command, **kwargs):
        commands.append(command)
        return standing_module.subprocess.CompletedProcess(command, 1, "", "stopped by the test")

    monkeypatch.setattr(standing_module.subprocess, "run", refuse)
    with pytest.raises(standing_module.StandingError, match="stopped by the test"):
        standing_module.validate(config, standing_module.SHIPPED, tmp_path)
    command = commands[0]
    assert command[command.index("--replay-init-strength") + 1] == "0.25"
    assert command[command.index("--replay-anchored") + 1] == "true" and "--replay-per-object" not in command
    key = {"checkpoint_sha256": checkpoint_fingerprint(standing_module.SHIPPED),
           **standing_module.validation_key(config)}
    assert key["replay_anchored"] is True and key["replay_timing"] == TIMING_MODEL
    cache = tmp_path / standing_module.RESULTS_DIR / f"{key['checkpoint_sha256'][:24]}.json"
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({"key": key, "results": {"moved": "cached"}}))
    assert standing_module.validate(config, standing_module.SHIPPED, tmp_path) == {"moved": "cached"}
    # a result validated before the priors' timing was part of the key was read with another timing: validated again
    cache.write_text(json.dumps({"key": {name: value for name, value in key.items() if name != "replay_timing"},
                                 "results": {"moved": "cached"}}))
    with pytest.raises(standing_module.StandingError, match="stopped by the test"):
        standing_module.validate(config, standing_module.SHIPPED, tmp_path)
    unreplayed = standing_module.validation_key(StandingConfig())
    assert "replay_anchored" not in unreplayed and "replay_timing" not in unreplayed  # caches without a replay stay


def test_figures_carry_the_intervals_over_tasks_and_the_curve_draws_them_where_present(tmp_path):
    result = _action_error(0.8)
    figure = figures(result)
    assert figure["vs_holding_still_interval"] == result["intervals"]["vs_holding_still"]
    assert figure["context_gain_interval"] == result["intervals"]["context_gain_translation"]
    low, high = figure["vs_holding_still_interval"]
    assert low < figure["vs_holding_still"] < high
    assert per_task(result) == {key: result[key] for key in ("seed", "frames_per_task", "horizon_T", "per_task")}
    # an old point (no intervals), then new ones: each point carries what its run had; the picture takes both
    run, standing, curve = tmp_path / "run", tmp_path / "standing", tmp_path / "curve.json"
    keep(_save(run, 100, [_entry(0.9, 0.6, 800)]), standing, curve)
    keep(_save(run, 200, [_entry(0.85, 0.55, 1600, per_task_kept=True)]), standing, curve)
    points = json.loads(curve.read_text())["points"]
    assert "moved_vs_holding_still_interval" not in points[0]
    assert points[1]["moved_vs_holding_still_interval"] == figures(_action_error(0.85))["vs_holding_still_interval"]
    assert points[1]["one_layout_context_gain_interval"] == figures(_action_error(0.55))["context_gain_interval"]
    assert curve.with_suffix(".png").stat().st_size > 10_000
    # a point whose interval is null (one task) draws without a bar
    plot_curve([*points, {**points[1], "samples_total": 2400, "moved_vs_holding_still_interval": None}],
               tmp_path / "mixed.png")
    assert (tmp_path / "mixed.png").stat().st_size > 10_000


def test_the_paired_difference_from_the_best_is_recorded_where_the_best_kept_its_per_task_errors(tmp_path):
    run, standing, curve = tmp_path / "run", tmp_path / "standing", tmp_path / "curve.json"
    first = keep(_save(run, 100, [_entry(0.9, 0.6, 800)]), standing, curve)  # an old record, nothing kept before
    assert first["best"] and first["against_best"] is None
    assert "against_best" not in read_record(standing / "last")["runs"][-1]
    second = keep(_save(run, 200, [_entry(0.85, 0.55, 1600, per_task_kept=True)]), standing, curve)
    assert second["best"]  # the rule is unchanged: better point estimates on both sets
    for name in ("moved", "one_layout"):  # the best's record is older than per-task errors: not compared
        assert "lacks" in second["against_best"][name]["not_compared"]
    assert second["against_best"]["best_end_step"] == 100
    third = keep(_save(run, 300, [_entry(0.8, 0.58, 2400, per_task_kept=True)]), standing, curve)
    assert not third["best"]  # worse on one layout
    recorded = read_record(standing / "last")["runs"][-1]["against_best"]
    assert recorded == third["against_best"] and recorded["best_end_step"] == 200
    moved = recorded["moved"]["vs_holding_still"]
    assert (moved["a"], moved["b"]) == (pytest.approx(0.8, abs=1e-3), pytest.approx(0.85, abs=1e-3))
    assert moved["difference"] == pytest.approx(-0.05, abs=1e-3) and moved["ci95"][0] < moved["difference"] < 0
    assert recorded["one_layout"]["vs_holding_still"]["difference"] == pytest.approx(0.03, abs=1e-3)
    assert recorded["moved"]["context_gain_translation"]["difference"] == pytest.approx(0.0, abs=1e-3)
    # the best's own record is left as it was when it was kept
    assert read_record(standing / "best")["runs"][-1]["end_step"] == 200


def _shipped(moved: float, one_layout: float) -> dict:
    """The shipped checkpoint's validation as :func:`shipped_validation` returns it."""
    return validation_record({"moved": _action_error(moved), "one_layout": _action_error(one_layout)})


def _compared(moved: float, one_layout: float, samples_total: int, shipped: dict) -> dict:
    entry = _entry(moved, one_layout, samples_total, per_task_kept=True)
    return {**entry, "against_shipped": paired_against(entry, shipped)}


def test_step_5_is_due_once_the_best_save_beats_the_shipped_checkpoint_on_both_sets(tmp_path):
    run, standing, curve = tmp_path / "run", tmp_path / "standing", tmp_path / "curve.json"
    shipped = _shipped(0.9, 0.6)
    unknown = keep(_save(run, 100, [_entry(0.95, 0.65, 800, per_task_kept=True)]), standing, curve)
    assert unknown["best"] and unknown["best_beats_shipped"] is None  # never compared with the shipped checkpoint
    first = keep(_save(run, 200, [_compared(0.8, 0.62, 1600, shipped)]), standing, curve)
    assert first["best"] and first["best_beats_shipped"] is False  # closer on moved objects only
    against = read_record(standing / "last")["runs"][-1]["against_shipped"]
    assert against["moved"]["vs_holding_still"]["difference"] == pytest.approx(-0.1, abs=1e-3)
    assert against["one_layout"]["vs_holding_still"]["difference"] == pytest.approx(0.02, abs=1e-3)
    # beats the shipped checkpoint on both sets but not the best on moved objects: the best, and so the answer, stay
    second = keep(_save(run, 300, [_compared(0.85, 0.58, 2400, shipped)]), standing, curve)
    assert not second["best"] and second["best_beats_shipped"] is False
    third = keep(_save(run, 400, [_compared(0.78, 0.55, 3200, shipped)]), standing, curve)
    assert third["best"] and third["best_beats_shipped"] is True
    assert read_record(standing / "best")["runs"][-1]["best_beats_shipped"] is True
    # a later run that is not kept leaves the answer with the best that is
    fourth = keep(_save(run, 500, [_compared(0.95, 0.7, 4000, shipped)]), standing, curve)
    assert not fourth["best"] and fourth["best_beats_shipped"] is True


def test_the_shipped_checkpoint_is_validated_once_and_again_only_when_its_key_changes(tmp_path, monkeypatch):
    calls = []

    def validate(config, checkpoint, root):
        calls.append((checkpoint, config.val_tasks))
        return {"moved": _action_error(0.9), "one_layout": _action_error(0.6)}

    monkeypatch.setattr(standing_module, "validate", validate)
    config = StandingConfig()
    first = shipped_validation(config, tmp_path / "validation", tmp_path / "standing")
    assert calls == [(standing_module.SHIPPED, 96)]
    assert first["validation"]["moved"] == figures(_action_error(0.9))
    assert first["key"]["checkpoint_sha256"] and set(first["key"]["presets_sha256"]) == {"moved", "one_layout"}
    again = shipped_validation(config, tmp_path / "validation", tmp_path / "standing")
    assert again == first and len(calls) == 1  # read from shipped.json
    shipped_validation(StandingConfig(val_tasks=12), tmp_path / "validation", tmp_path / "standing")
    assert calls[-1] == (standing_module.SHIPPED, 12)  # another validation size: validated again
    assert json.loads((tmp_path / "standing" / SHIPPED_RECORD).read_text())["key"]["val_tasks"] == 12


def test_a_device_save_not_compared_with_the_shipped_checkpoint_is_compared_here_on_the_cpu(tmp_path, monkeypatch):
    validated = []

    def validate(config, checkpoint, root):
        validated.append((checkpoint, config.device, root))
        return {"moved": _action_error(0.9), "one_layout": _action_error(0.6)}

    monkeypatch.setattr(standing_module, "validate", validate)
    work = tmp_path / "work"
    for name in standing_module.VALIDATION_CONFIGS:  # the sets are here already: nothing is generated
        (work / "validation" / name / "meta").mkdir(parents=True)
        (work / "validation" / name / "meta" / "info.json").write_text("{}")
    entry = _entry(0.8, 0.5, 5600, per_task_kept=True)
    entry["config"] = asdict(StandingConfig(device="cuda", out="/device/out", work=str(work)))
    entry["against_shipped"] = {name: {"not_compared": "no shipped checkpoint on the device"}
                                for name in standing_module.VALIDATION_CONFIGS}
    save = _save(tmp_path / "device", 700, [entry])
    pack(save, tmp_path / "out")
    result = accept(tmp_path / "out", tmp_path / "standing", tmp_path / "curve.json")
    assert validated == [(standing_module.SHIPPED, "cpu", work / "validation")]
    assert result["best_beats_shipped"] is True  # 0.8 against 0.9 and 0.5 against 0.6
    against = read_record(tmp_path / "standing" / "last")["runs"][-1]["against_shipped"]
    assert against["one_layout"]["vs_holding_still"]["difference"] == pytest.approx(-0.1, abs=1e-3)
    assert json.loads((tmp_path / "standing" / SHIPPED_RECORD).read_text())["key"]["device"] == "cpu"


def _point(samples: int, moved: float, one_layout: float) -> dict:
    return {"samples_total": samples, "moved_vs_holding_still": moved, "moved_context_gain": 1.3,
            "one_layout_vs_holding_still": one_layout, "one_layout_context_gain": 1.3 + (1 - one_layout)}


def test_the_trend_says_at_what_scale_each_figure_meets_its_aim_and_where_none_is_predicted(tmp_path, capsys):
    # moved objects fall 0.1 a tenfold from 0.9 at 10^4 samples: 0.5 at 10^8; one layout wobbles about 0.6 (noisy)
    points = [_point(10 ** k, 1.3 - 0.1 * k, 0.6 + 0.02 * (-1) ** k) for k in range(4, 8)]
    points.append(_point(100, 0.2, 0.2))  # an earlier recipe's point, left out by min_samples
    result = trend(points, min_samples=10_000)
    assert result["points"] == 4 and result["samples"] == [10_000, 10_000_000]
    moved = result["moved_vs_holding_still"]
    assert moved["slope_per_decade"] == pytest.approx(-0.1) and moved["at_last_point"] == pytest.approx(0.6)
    assert moved["samples_at_target"] == pytest.approx(1e8, rel=1e-6)  # an exact line: the interval closes on it
    assert moved["samples_at_target_interval"] == [pytest.approx(1e8, rel=1e-6)] * 2
    layout = result["one_layout_vs_holding_still"]
    low, high = layout["slope_interval"]
    assert low < 0 < high  # no trend: the slope's interval holds flat, so the far end is unbounded
    assert layout["samples_at_target_interval"][1] is None
    gain = result["moved_context_gain"]  # flat at 1.3: it never reaches 2
    assert gain["slope_per_decade"] == pytest.approx(0.0, abs=1e-9) and gain["samples_at_target"] is None
    with pytest.raises(ValueError, match="at least 3 points"):
        trend(points, min_samples=10 ** 6)
    # the command line reads the curve's file
    from workbench.cli.standing import main

    curve = tmp_path / "curve.json"
    curve.write_text(json.dumps({"points": points}))
    assert main(["--curve", str(curve), "trend", "--min-samples", "10000"]) == 0
    assert json.loads(capsys.readouterr().out)["moved_vs_holding_still"]["target"] == 0.5


def test_a_study_arm_resumes_the_save_with_its_own_peak_rate_and_weight_decay(tmp_path):
    """The arm's rate and decay reach the optimizer LeRobot rebuilds on resume, the schedule going on at its step."""
    from lerobot.optim.optimizers import load_optimizer_state
    from lerobot.optim.schedulers import load_scheduler_state
    from torch.optim import AdamW
    from torch.optim.lr_scheduler import LambdaLR

    last = Path("checkpoints/stream/last")
    save = tmp_path / "last"
    for part in ("pretrained_model", "training_state"):
        (save / part).mkdir(parents=True)
    for source in (last / "training_state").iterdir():
        (save / "training_state" / source.name).write_bytes(source.read_bytes())
    (save / "pretrained_model" / "train_config.json").write_bytes((last / "pretrained_model" / "train_config.json")
                                                                  .read_bytes())
    saved_groups = json.loads((save / "training_state" / "optimizer_param_groups.json").read_text())
    factor = saved_groups[0]["lr"] / saved_groups[0]["initial_lr"]  # the schedule's factor at the saved step

    staged = standing_module._stage_resume(save, tmp_path / "run", base_lr=5e-4, weight_decay=0.1)
    assert staged.name == f"{standing_module.step_of(save):09d}"
    params = [torch.nn.Parameter(torch.zeros(1)) for _ in saved_groups[0]["params"]]
    # built from the config as LeRobot builds them (the scheduler adds initial_lr), then loaded
    optimizer = AdamW(params, lr=2e-4, weight_decay=0.01, fused=True)
    scheduler = LambdaLR(optimizer, lambda step: factor)
    optimizer = load_optimizer_state(optimizer, staged / "training_state")
    scheduler = load_scheduler_state(scheduler, staged / "training_state")
    assert optimizer.param_groups[0]["weight_decay"] == 0.1
    assert optimizer.param_groups[0]["lr"] == pytest.approx(5e-4 * factor)
    assert scheduler.base_lrs == [5e-4]
    scheduler.step()
    assert optimizer.param_groups[0]["lr"] == pytest.approx(5e-4 * factor)  # the schedule's next rate: the arm's
    train_config = json.loads((staged / "pretrained_model" / "train_config.json").read_text())
    assert train_config["optimizer"]["lr"] == 5e-4 and train_config["policy"]["optimizer_weight_decay"] == 0.1
    untouched = standing_module._stage_resume(save, tmp_path / "control")  # the control arm: the save as it is
    assert (untouched / "training_state" / "scheduler_state.json").read_bytes() == \
        (save / "training_state" / "scheduler_state.json").read_bytes()


def test_compare_validates_each_checkpoint_once_and_pairs_the_rest_against_the_first(tmp_path, monkeypatch,
                                                                                     held_out_pseudo_tasks, capsys):
    """A real validation (the shipped checkpoint, 2 held-out tasks × 1 frame on each set) is cached by the
    checkpoint's contents: a copy elsewhere is read back, not run again, and pairs with the original at zero."""
    from workbench.cli.standing import main

    root = tmp_path / "work" / "validation"
    root.mkdir(parents=True)
    for name in standing_module.VALIDATION_CONFIGS:  # both sets: the session's held-out pseudo-tasks
        (root / name).symlink_to(held_out_pseudo_tasks, target_is_directory=True)
    copy = tmp_path / "copy" / "pretrained_model"
    shutil.copytree(standing_module.SHIPPED, copy)
    config = StandingConfig(work=str(tmp_path / "work"), val_tasks=2, val_frames_per_task=1)
    runs = []
    real_run = standing_module.subprocess.run
    monkeypatch.setattr(standing_module.subprocess, "run",
                        lambda *a, **k: runs.append({**k, "command": a[0]}) or real_run(*a, **k))
    result = standing_module.compare(config, [standing_module.SHIPPED, copy.parent], root)
    assert len(runs) == 2  # one lerobot-ip-action-error per set, for the first; the copy came from the cache
    assert all(run["env"]["OMP_NUM_THREADS"] == "1" for run in runs)  # one thread beside the training
    assert len(list((root / standing_module.RESULTS_DIR).glob("*.json"))) == 1
    reference, other = result["checkpoints"]
    assert reference["against_reference"] is None and other["checkpoint"] == str(copy)
    for name in standing_module.VALIDATION_CONFIGS:
        assert reference["validation"][name] == other["validation"][name]
        assert other["against_reference"][name]["vs_holding_still"]["difference"] == 0.0
        assert other["against_reference"][name]["clusters"] == 2
    # the command line reads the same cache and prints the same comparison
    assert main(["compare", str(standing_module.SHIPPED), str(copy), "--work", str(tmp_path / "work"),
                 "--val-tasks", "2", "--val-frames-per-task", "1"]) == 0
    assert json.loads(capsys.readouterr().out)["checkpoints"][1]["validation"] == other["validation"]
    assert len(runs) == 2
    with pytest.raises(FileNotFoundError, match="neither a pretrained_model folder"):
        standing_module.compare(config, [tmp_path], root)
    other_size = StandingConfig(work=str(tmp_path / "work"), val_tasks=1, val_frames_per_task=1)
    assert standing_module.validation_key(other_size) != standing_module.validation_key(config)
    # started from the replay: its own cache entry, the flags on the command, the replay's figures beside the policy's
    assert main(["compare", str(standing_module.SHIPPED), "--work", str(tmp_path / "work"), "--val-tasks", "2",
                 "--val-frames-per-task", "1", "--replay-init-strength", "0.25", "--replay-per-object", "true"]) == 0
    replayed = json.loads(capsys.readouterr().out)["checkpoints"][0]["validation"]
    assert len(runs) == 4 and runs[-1]["command"][-4:] == ["--replay-init-strength", "0.25", "--replay-per-object",
                                                           "true"]
    for name in standing_module.VALIDATION_CONFIGS:
        figures = replayed[name]
        # replay_vs_holding_still is rounded to 0.001, coarse where the replay is within a fraction of a millimetre
        ratio, half_unit = figures["translation_mm"] / figures["hold_translation_mm"], 5e-4
        low, high = ratio / (figures["replay_vs_holding_still"] + half_unit), ratio / max(
            figures["replay_vs_holding_still"] - half_unit, 1e-9)
        assert low * (1 - 1e-3) <= figures["vs_replay"] <= high * (1 + 1e-3)
        assert figures["vs_replay_interval"][0] <= figures["vs_replay"] <= figures["vs_replay_interval"][1]


def test_the_best_holds_the_moving_average_where_it_validated_closer_than_the_raw_weights(tmp_path):
    """A run that kept a moving average offers whichever of its raw weights and their average validated closer on
    both sets; the last save is kept compactly: the average as its weights (the run continues from it), neither
    moments nor a second average in its training state, and a best that is the average is the same file's bytes."""
    from safetensors.torch import load_file, save_file

    from lerobot_instant_policy.training.weight_average import AVERAGE_FILE

    def save_with_average(step: int, raw_value: float, average_value: float, moved: float, average_moved: float,
                          layout: float = 0.6):
        save = _save(tmp_path / "run", step)
        save_file({"w": torch.full((2,), raw_value), "frozen": torch.zeros(1)},
                  str(save / "pretrained_model" / "model.safetensors"))
        save_file({"w": torch.full((2,), average_value)}, str(save / "training_state" / AVERAGE_FILE),
                  metadata={"decay": "0.999", "updates": str(step)})
        entry = _entry(moved, layout, step * 8, per_task_kept=True)
        average = _entry(average_moved, layout - 0.02, step * 8, per_task_kept=True)
        entry["average"] = {key: average[key] for key in ("validation", "validation_per_task")}
        entry["average"]["against_shipped"] = {}
        (save / RECORD).write_text(json.dumps({"runs": [entry]}))
        return save

    def weights(folder: Path) -> torch.Tensor:
        return load_file(folder / "pretrained_model" / "model.safetensors")["w"]

    standing, curve = tmp_path / "standing", tmp_path / "curve.json"
    first = keep(save_with_average(100, 1.0, 3.0, 0.9, 0.85), standing, curve)  # the average closer on both sets
    assert first["best"]
    assert torch.equal(weights(standing / "best"), torch.full((2,), 3.0))
    best_entry = read_record(standing / "best")["runs"][-1]
    assert best_entry["readout"] == "average"
    assert best_entry["validation"]["moved"]["vs_holding_still"] == pytest.approx(0.85, abs=0.01)
    assert torch.equal(weights(standing / "last"), torch.full((2,), 3.0))
    assert not (standing / "last" / "training_state" / AVERAGE_FILE).exists()
    assert (standing / "last" / "training_state" / "training_step.json").is_file()
    assert ((standing / "best" / "pretrained_model" / "model.safetensors").read_bytes()
            == (standing / "last" / "pretrained_model" / "model.safetensors").read_bytes())
    assert json.loads(curve.read_text())["points"][-1]["moved_vs_holding_still"] == pytest.approx(0.9, abs=0.01)  # raw
    # an average worse than its raw weights on one set: the raw weights are the run's offer
    second = keep(save_with_average(200, 5.0, 7.0, 0.8, 0.95, layout=0.55), standing, curve)
    assert second["best"] and read_record(standing / "best")["runs"][-1]["readout"] == "raw"
    assert torch.equal(weights(standing / "best"), torch.full((2,), 5.0))
    assert torch.equal(weights(standing / "last"), torch.full((2,), 7.0))  # the run goes on from its average
    assert second["against_best"]["moved"]["vs_holding_still"]["b"] == pytest.approx(0.85, abs=0.01)


def test_a_run_whose_process_stopped_is_concluded_from_its_folder(tmp_path, monkeypatch):
    """``conclude``: the last complete save after the staged start is validated, recorded after the start's record
    and kept; the start's staged copy and an incomplete save are not taken."""
    monkeypatch.setattr(standing_module, "validate",
                        lambda config, checkpoint, root: {"moved": _action_error(0.7), "one_layout": _action_error(0.5)})
    monkeypatch.setattr(standing_module, "validation_sets", lambda config, root: {})
    standing, curve = tmp_path / "standing", tmp_path / "curve.json"
    keep(_save(tmp_path / "before", 1000, [_entry(0.9, 0.6, 8000, per_task_kept=True)]), standing, curve)
    train_dir = tmp_path / "work" / "run-20261128T055407"
    staged = train_dir / "checkpoints" / "000001000"
    shutil.copytree(standing / "last", staged)
    last_save = _save(train_dir, 1500)
    (last_save / "training_state" / "task_pool.json").write_text(json.dumps(
        {"start_task": 0, "stats": {"distinct_tasks_used": 210, "elapsed_s": 400.0}}))
    (last_save / "pretrained_model" / "config.json").write_text(json.dumps({"hidden_dim": 128}))
    _save(train_dir, 2000, complete=False)  # stopped while saving
    config = StandingConfig(work=str(tmp_path / "work"))
    record = standing_module.conclude_stopped(config, train_dir, standing, curve)
    entry = record["runs"][-1]
    assert len(record["runs"]) == 2 and entry["start_step"] == 1000 and entry["end_step"] == 1500
    assert entry["samples"] == 500 * config.batch_size and entry["samples_total"] == 8000 + 500 * config.batch_size
    assert entry["tasks"] == 210
    assert entry["started"] == "2026-11-28T05:54:07+00:00" and entry["wall_s"] > 0
    assert (standing / "last" / "pretrained_model" / "model.safetensors").read_text() == "weights 1500"
    assert len(json.loads(curve.read_text())["points"]) == 2


def test_validation_generators_that_print_much_do_not_block(tmp_path, monkeypatch):
    """A generator's output goes to a log, not to a pipe nobody reads until the end (which filled at 64 KiB and stopped
    the generators mid-set); a failing one's error names the tail of its log."""
    import sys

    speak = "import sys; sys.stderr.write('x' * 400_000); sys.exit(int('local/one_layout' in sys.argv))"
    monkeypatch.setattr(standing_module, "program", lambda name: [sys.executable, "-c", speak])
    generating = standing_module.validation_sets(StandingConfig(), tmp_path)
    with pytest.raises(standing_module.StandingError, match="one_layout validation set failed: x+$"):
        standing_module.wait_for(generating, tmp_path)
    assert (tmp_path / "moved.log").stat().st_size == 400_000


def test_a_compact_save_resumes_from_its_average_and_rebuilds_the_moments_before_moving(tmp_path, pool_run):
    """A real pool run's save (the session's ``pool_run``), kept compactly (:func:`write_compact`: the average as the
    weights, no moments, no second average), resumes under ``lerobot-ip-train --resume=true`` as the standing run
    stages it: the optimizer starts fresh and takes its rebuild steps at learning rate 0, so the weights after them are
    the compact save's bit for bit, and the steps after move them."""
    import os
    import subprocess
    import sys

    from safetensors.torch import load_file

    from lerobot_instant_policy.training.weight_average import AVERAGE_FILE

    save = pool_run / "run" / "checkpoints" / "000002"
    compact = tmp_path / "last"
    standing_module.write_compact(save, compact)
    assert not any((compact / "training_state" / name).exists() for name in ("optimizer_state.safetensors",
                                                                             AVERAGE_FILE))
    average = load_file(save / "training_state" / AVERAGE_FILE)
    weights = load_file(compact / "pretrained_model" / "model.safetensors")
    assert all(torch.equal(weights[name], tensor) for name, tensor in average.items())

    resumed = tmp_path / "resumed"
    staged = standing_module._stage_resume(compact, resumed)
    config = StandingConfig(moment_rebuild_steps=2, average_decay=0.5)
    resume_flags = [flag for flag in train_command(config, staged, resumed) if flag.startswith(
        ("--config_path", "--resume", "--optimizer.", "--output_dir", "--average"))]
    command = [str(Path(sys.executable).parent / "lerobot-ip-train"), f"--stream.config={pool_run / 'stream.json'}",
               "--stream.samples_per_task=2", "--stream.tasks_per_render=1", "--pool", "--pool.min_tasks=1",
               "--pool.capacity=4", "--save_freq=2", "--log_freq=1", *resume_flags, "--steps=6"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=tmp_path,
                          env={**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"})
    assert done.returncode == 0, done.stderr[-3000:]
    after_rebuild = load_file(resumed / "checkpoints" / "000004" / "pretrained_model" / "model.safetensors")
    moved = load_file(resumed / "checkpoints" / "000006" / "pretrained_model" / "model.safetensors")
    assert all(torch.equal(after_rebuild[name], weights[name]) for name in average)
    assert any(not torch.equal(moved[name], weights[name]) for name in average)
