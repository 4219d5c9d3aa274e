"""``python -m workbench.cli.train_rounds`` (``make train-gpu``, ``make campaign``): the commands of every stage,
refused settings, the state file that makes a run resumable, the runner that skips finished stages and stops its
processes, and a tiny run on CPU end to end (generation beside training, the training dataset growing, training
resumed, the frame-encoding cache extended, an interruption resumed, the action error and loss curve at the end)."""

from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from workbench import train_rounds as rounds
from workbench.cli import train_rounds
from workbench.cli.train_rounds import main
from workbench.train_rounds import (
    Layout,
    Runner,
    Stage,
    Step,
    TrainRoundsConfig,
    TrainRoundsError,
    read_state,
    write_state,
)

REPO = Path(__file__).resolve().parents[2]  # the repository root, from which workbench runs
TINY = ["--family", "reach", "--rounds", "2", "--tasks-per-round", "2", "--demos-per-task", "3",
        "--steps-per-round", "4", "--batch-size", "2", "--workers", "1", "--num-workers", "0", "--device", "cpu",
        "--val-tasks", "2", "--val-demos-per-task", "3"]


def _commands(output: str) -> list[tuple[bool, list[str]]]:
    """The dry run's command lines as (runs in the background, argv)."""
    commands = []
    for line in output.splitlines():
        background = line.startswith("&   ")
        line = line.removeprefix("&   ")
        if line and not line.startswith("#"):
            commands.append((background, shlex.split(line)))
    return commands


def _name(argv: list[str]) -> str:
    """The command an argv runs: a console script's name or the module after ``-m``."""
    return argv[argv.index("-m") + 1] if "-m" in argv else Path(argv[0]).name


def test_dry_run_prints_the_command_of_every_stage_and_runs_nothing(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["--out", str(out), *TINY, "--policy.use_amp=false", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert not out.exists()
    commands = _commands(printed)
    assert [(background, _name(argv)) for background, argv in commands] == [
        (False, "lerobot-ip-generate"),  # round 0: the only generation training waits for
        (False, "lerobot-train"),  # round 0 ...
        (True, "lerobot-ip-generate"),  # ... beside the validation set
        (True, "lerobot-ip-generate"),  # ... and round 1
        (False, "lerobot-train"),  # round 1 on the grown data
        (False, "lerobot-ip-action-error"),
        (False, "lerobot-ip-loss-curve"),
    ]
    for stage in ("append-000", "stage-append-001", "append-001"):
        assert f"# {stage}:" in printed
    generate_0, train_0, val, generate_1, train_1, action_error, loss_curve = (argv for _, argv in commands)
    assert generate_0[generate_0.index("--out") + 1] == str(out / "rounds" / "round-000")
    assert generate_0[generate_0.index("--seed") + 1] == "31" and generate_1[generate_1.index("--seed") + 1] == "32"
    assert val[val.index("--object-split") + 1] == "held_out" and val[val.index("--out") + 1] == str(out / "val")
    assert "--policy.type=instant_policy" in train_0 and "--steps=4" in train_0 and "--policy.device=cpu" in train_0
    assert f"--dataset.root={out / 'train'}" in train_0 and f"--output_dir={out / 'run'}" in train_0
    assert "--save_freq=2" in train_0
    # a fresh start is the config's defaults (the shipped model) with the --policy.* passthrough; resumed rounds keep
    # the saved config
    assert [arg for arg in train_0 if arg.startswith("--policy.") and arg != "--policy.device=cpu"] == [
        "--policy.type=instant_policy", "--policy.use_amp=false"]
    last = out / "run" / "checkpoints" / "last" / "pretrained_model"
    assert train_1[1:] == [f"--config_path={last / 'train_config.json'}", "--resume=true", "--steps=8"]
    assert action_error[action_error.index("--policy-path") + 1] == str(last)
    assert action_error[action_error.index("--N") + 1] == "2" and "--device" in action_error
    assert loss_curve[loss_curve.index("--train-root") + 1] == str(out / "train")


def test_dry_run_from_the_shipped_checkpoint_under_accelerate(tmp_path, capsys):
    launcher = "accelerate launch --multi_gpu --num_processes=4"
    assert main(["--out", str(tmp_path / "run"), *TINY, "--start", "shipped", "--launcher", launcher,
                 "--dry-run"]) == 0
    trains = [argv for _, argv in _commands(capsys.readouterr().out)
              if any(Path(arg).name == "lerobot-train" or arg == "lerobot.scripts.lerobot_train" for arg in argv)]
    assert len(trains) == 2
    for argv in trains:
        assert argv[:4] == shlex.split(launcher)
    assert f"--policy.path={SHIPPED_CHECKPOINT}" in trains[0]
    assert not any(arg.startswith("--policy.type") or arg.startswith("--policy.preset") for arg in trains[0])


def test_the_one_layout_fraction_anneals_over_the_rounds_and_the_last_entry_repeats(tmp_path, capsys):
    """``--shared-layout-fractions 0.5 0``: round 0 generates half one-layout tasks, every later round moved objects
    only; the validation set keeps the generation config's setting (no flag)."""
    assert main(["--out", str(tmp_path / "run"), *TINY, "--rounds", "3", "--shared-layout-fractions", "0.5", "0",
                 "--dry-run"]) == 0
    generations = [argv for _, argv in _commands(capsys.readouterr().out) if _name(argv) == "lerobot-ip-generate"]
    fractions = {argv[argv.index("--out") + 1]: argv[argv.index("--shared-layout-fraction") + 1]
                 if "--shared-layout-fraction" in argv else None for argv in generations}
    run = tmp_path / "run"
    assert fractions == {str(run / "rounds" / "round-000"): "0.5", str(run / "val"): None,
                         str(run / "rounds" / "round-001"): "0.0", str(run / "rounds" / "round-002"): "0.0"}


def test_the_layout_shift_grows_over_the_rounds_and_an_unset_schedule_keeps_older_runs_resumable(tmp_path, capsys):
    """``--layout-shifts 0.25 1``: round 0 moves the objects a quarter of the way, later rounds draw them anew; the
    validation set keeps the generation config's setting. A run without the schedule keeps the plan it had before
    the setting existed, so its saved state still resumes."""
    assert main(["--out", str(tmp_path / "run"), *TINY, "--rounds", "3", "--layout-shifts", "0.25", "1",
                 "--dry-run"]) == 0
    generations = [argv for _, argv in _commands(capsys.readouterr().out) if _name(argv) == "lerobot-ip-generate"]
    shifts = {Path(argv[argv.index("--out") + 1]).name: argv[argv.index("--layout-shift") + 1]
              if "--layout-shift" in argv else None for argv in generations}
    assert shifts == {"round-000": "0.25", "val": None, "round-001": "1.0", "round-002": "1.0"}
    assert "layout_shifts" not in TrainRoundsConfig().plan()
    assert TrainRoundsConfig(layout_shifts=[0.5]).plan()["layout_shifts"] == [0.5]


@pytest.mark.parametrize(("args", "message"), [
    (["--shared-layout-fractions", "0.5", "1.5"], "shared_layout_fractions must be a non-empty list of numbers in"),
    (["--layout-shifts", "-0.1"], "layout_shifts must be a non-empty list of numbers in [0, 1]"),
    (["--steps-per-round", "0"], "steps_per_round must be a positive integer"),
    (["--rounds", "-1"], "rounds must be a positive integer"),
    (["--val-demos-per-task", "2"], "val_demos_per_task must be at least 3"),
    (["--demos-per-task", "1"], "demos_per_task must be at least 2"),
    (["--start", "no/such/checkpoint"], "start must be 'fresh', 'shipped' or a pretrained_model directory"),
    (["--seed", "120"], "val_seed 121 is the seed of a training round"),
    (["--dataset.root=x"], "unrecognized arguments: --dataset.root=x"),
])
def test_bad_settings_are_refused_with_a_message(tmp_path, capsys, args, message):
    assert main(["--out", str(tmp_path / "run"), *TINY, *args, "--dry-run"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_the_state_file_belongs_to_one_plan(tmp_path, capsys):
    config = TrainRoundsConfig(out=str(tmp_path / "run"), device="cpu", workers=1)
    layout = Layout(config.out)
    state = read_state(config, layout)
    assert state["stages"] == {} and state["plan"]["steps_per_round"] == 1000 and "out" not in state["plan"]
    state["stages"]["generate-000"] = 1.5
    write_state(layout, state)
    # the same plan continues; more rounds, other process counts or another device are the same run
    again = TrainRoundsConfig(out=config.out, device="cuda", workers=12, rounds=9)
    assert read_state(again, layout)["stages"] == {"generate-000": 1.5}
    # other data or training settings are another run: refused, naming what differs, from the command line too
    with pytest.raises(TrainRoundsError, match=r"holds another run .*\['batch_size', 'steps_per_round'\]"):
        read_state(TrainRoundsConfig(out=config.out, steps_per_round=10, batch_size=8), layout)
    assert main(["--out", config.out, *TINY]) == 2
    assert "holds another run" in capsys.readouterr().err
    # a directory with other things in it and no state file is not taken over
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(TrainRoundsError, match="not empty and holds no state.json"):
        read_state(TrainRoundsConfig(out=str(tmp_path / "other")), Layout(tmp_path / "other"))


def _fake_checkpoint(layout: Layout, step: int) -> Path:
    """A checkpoint directory as lerobot-train leaves it, holding only what the runner reads."""
    checkpoint = layout.run / "checkpoints" / f"{step:06d}"
    (checkpoint / "pretrained_model").mkdir(parents=True)
    (checkpoint / "pretrained_model" / "train_config.json").write_text("{}")
    (checkpoint / "training_state").mkdir()
    (checkpoint / "training_state" / "training_step.json").write_text(json.dumps({"step": step}))
    return checkpoint


def test_training_resumes_the_latest_checkpoint_and_more_rounds_than_asked_are_refused(tmp_path, capsys):
    out = tmp_path / "run"
    config = train_rounds.config_from_args(train_rounds.build_parser().parse_args(["--out", str(out), *TINY]), [])
    layout = Layout(out)
    write_state(layout, read_state(config, layout))
    assert layout.latest_checkpoint() is None and layout.trained_steps() == 0
    _fake_checkpoint(layout, 2)
    at_4 = _fake_checkpoint(layout, 4)
    # killed before "last" pointed at step 4: the latest numbered checkpoint is resumed
    assert layout.latest_checkpoint() == at_4 and layout.trained_steps() == 4
    assert f"--config_path={at_4 / 'pretrained_model' / 'train_config.json'}" in (
        rounds.train_command(config, layout, 1, layout.latest_checkpoint()))
    (layout.run / "checkpoints" / "last").symlink_to("000002")
    assert layout.latest_checkpoint() == layout.last_checkpoint and layout.trained_steps() == 2

    _fake_checkpoint(layout, 8)
    (layout.run / "checkpoints" / "last").unlink()
    assert main(["--out", str(out), *TINY, "--rounds", "1"]) == 2
    assert "has trained 8 steps, more than 1 rounds of 4: pass --rounds 2 or more" in capsys.readouterr().err


def _python(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def test_the_runner_skips_recorded_stages_and_stops_the_background_when_a_stage_fails(tmp_path):
    """First invocation: stage ``one`` runs, ``two`` fails while ``slow`` runs beside it; ``slow``'s process is
    stopped and neither is recorded. Second invocation: ``one`` is not run again, ``two`` and ``slow`` are, and a
    stage already finished on disk is recorded without running."""
    config = TrainRoundsConfig(out=str(tmp_path / "run"), device="cpu", workers=1)
    layout = Layout(config.out)
    counter, pid_file, fail_flag = tmp_path / "counter", tmp_path / "slow.pid", tmp_path / "fail"
    fail_flag.touch()
    wait_then_maybe_fail = (
        "import os, pathlib, sys, time\n"
        f"deadline = time.time() + 60\nwhile not pathlib.Path({str(pid_file)!r}).exists() and time.time() < deadline:"
        " time.sleep(0.05)\n"
        f"sys.exit(3 if os.path.exists({str(fail_flag)!r}) else 0)"
    )
    slow = ("import os, pathlib, time\n"
            f"pathlib.Path({str(pid_file)!r}).write_text(str(os.getpid()))\n"
            f"time.sleep(60 if os.path.exists({str(fail_flag)!r}) else 0)")
    steps = [
        Step(Stage("one", "count", command=lambda: _python(f"open({str(counter)!r}, 'a').write('one\\n')"))),
        Step(Stage("two", "wait for slow, fail while the flag exists", command=lambda: _python(wait_then_maybe_fail)),
             [Stage("slow", "sleep", command=lambda: _python(slow))]),
        Step(Stage("finished", "never runs", command=lambda: _python("raise SystemExit(5)"), done=lambda: True)),
    ]

    state = read_state(config, layout)
    runner = Runner(config, layout, state)
    started = time.perf_counter()
    runner.run_step(steps[0])
    with pytest.raises(TrainRoundsError, match=r"stage two failed \(exit code 3\)"):
        runner.run_step(steps[1])
    assert time.perf_counter() - started < 45  # slow's 60 s sleep was cut short
    with pytest.raises(ProcessLookupError):
        os.kill(int(pid_file.read_text()), 0)
    assert list(json.loads(layout.state.read_text())["stages"]) == ["one"]
    assert (layout.logs / "two.log").read_text().startswith(sys.executable)

    fail_flag.unlink()
    pid_file.unlink()
    runner = Runner(config, layout, read_state(config, layout))
    for step in steps:
        runner.run_step(step)
    assert counter.read_text() == "one\n"
    stages = json.loads(layout.state.read_text())["stages"]
    assert set(stages) == {"one", "two", "slow", "finished"} and stages["finished"] == 0.0
    assert not (layout.logs / "finished.log").exists()


def test_the_json_result_is_found_after_other_output():
    assert rounds.json_result('loading {x}\n{\n  "a": 1\n}\n') == {"a": 1}
    with pytest.raises(TrainRoundsError, match="no JSON result"):
        rounds.json_result("nothing here")


def _run_command(out: Path, config: Path) -> list[str]:
    """The command as ``make campaign`` runs it: ``python -m`` from the repository root (``_run_command``'s cwd)."""
    return [sys.executable, "-m", "workbench.cli.train_rounds", "--config", str(config), "--out", str(out), *TINY]


def _interruptible() -> None:
    """In the child before it starts: SIGINT back to its default, so Python installs its KeyboardInterrupt handler and
    the interruption below reaches the run as a user's Ctrl-C does, even where the tests run with SIGINT ignored (in a
    background job of a non-interactive shell, ``make test &`` or ``nohup``, children inherit the ignore)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow
def test_a_tiny_run_on_cpu_grows_its_data_resumes_training_extends_the_cache_and_survives_an_interruption(tmp_path):
    """2 rounds × 2 reach tasks × 3 demonstrations, 4 steps of batch 2 per round (about 3 minutes on 2 busy cores).
    The first invocation is interrupted once round 0 has trained; the second finishes the run."""
    config = tmp_path / "tiny.json"
    config.write_text(json.dumps({"loss_curve_samples": 8, "eval_frames_per_task": 1}))
    out = tmp_path / "run"
    layout = Layout(out)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "WANDB_MODE": "disabled"}
    first = subprocess.Popen(_run_command(out, config), env=env, cwd=REPO, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, preexec_fn=_interruptible)
    deadline = time.time() + 400
    while time.time() < deadline and first.poll() is None:
        if layout.state.is_file() and "train-000" in json.loads(layout.state.read_text())["stages"]:
            break
        time.sleep(0.2)
    first.send_signal(signal.SIGINT)
    _, first_err = first.communicate(timeout=120)
    assert first.returncode == 130, first_err[-3000:]
    assert "run the same command again to resume" in first_err
    interrupted = json.loads(layout.state.read_text())["stages"]
    assert "train-000" in interrupted and "loss-curve-000008" not in interrupted
    train_0_log = (layout.logs / "train-000.log").read_text()

    second = subprocess.run(_run_command(out, config), env=env, cwd=REPO, capture_output=True, text=True,
                            timeout=900)
    assert second.returncode == 0, second.stderr[-5000:]
    summary = json.loads(second.stdout)

    # round 0 was not trained again; round 1 resumed its checkpoint on the grown dataset
    assert (layout.logs / "train-000.log").read_text() == train_0_log
    train_1_log = (layout.logs / "train-001.log").read_text()
    assert "dataset.num_episodes=6" in train_0_log and "dataset.num_episodes=12" in train_1_log
    assert "--resume=true" in train_1_log.splitlines()[0] and "Resuming data order" in train_1_log
    checkpoints = out / "run" / "checkpoints"
    assert {"000002", "000004", "000006", "000008"} <= {path.name for path in checkpoints.iterdir()}
    assert json.loads((checkpoints / "last" / "training_state" / "training_step.json").read_text())["step"] == 8
    assert summary["steps"] == 8 and summary["episodes"] == 12 and summary["tasks"] == 4

    # the frame-encoding cache of round 0's frames was extended with round 1's, not rebuilt
    (cache,) = (out / "train" / "instant_policy_encodings").iterdir()
    meta = json.loads((cache / "meta.json").read_text())
    round_0_frames = meta["extended_from"]
    assert 0 < round_0_frames < summary["frames"] == meta["dataset"]["total_frames"]
    assert f"from {round_0_frames} to {summary['frames']} frames" in train_1_log
    assert f"encoded {round_0_frames} frames of" in train_0_log

    # the datasets: round directories gone once appended, the validation set held out, the training tasks by round
    assert not (out / "rounds").exists() and (out / "val" / "meta" / "info.json").is_file()
    lines = (out / "train" / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()
    tasks = [json.loads(line)["task"] for line in lines]
    assert [task.split("-")[1] for task in tasks] == ["s31", "s31", "s32", "s32"]

    # the results
    assert summary["action_error"]["N"] == 2 and summary["action_error"]["translation_mm"] > 0
    assert set(summary["context_gain"]) == {"translation", "rotation", "gripper"}
    assert json.loads((out / "action_error.json").read_text())["tasks"] == 2
    assert Path(summary["loss_curve"]["png"]).is_file() and summary["loss_curve"]["last"]["step"] == 8
    for stage in ("generate-000", "val", "generate-001", "train-000", "train-001", "action-error-000008"):
        assert stage in summary["minutes"]
    assert json.loads((out / "summary.json").read_text()) == summary


@pytest.mark.parametrize("name", sorted(path.name for path in (REPO / "configs" / "train_rounds").glob("*.json")))
def test_the_shipped_round_configs_are_valid_and_the_continued_campaign_starts_from_committed_weights(name, capsys,
                                                                                                       monkeypatch):
    """Every preset under configs/train_rounds validates and plans its stages; the continued campaign's start is the
    committed checkpoint (a fresh clone has no outputs/), on moved objects only."""
    repo = REPO
    monkeypatch.chdir(repo)
    assert main(["--config", f"configs/train_rounds/{name}", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    if name == "cpu_campaign_continue.json":
        assert f"--policy.path={repo / 'checkpoints' / 'campaign_015000'}" in printed
        assert "--shared-layout-fraction 0.0" in printed
        assert "--policy.optimizer_lr=2e-4" in printed  # a continued network restarts below its own peak lr
    if name == "cpu_campaign_shift.json":  # moves grow from a fifth of the way to the paper's independent draws
        assert "--layout-shift 0.2" in printed and "--layout-shift 1.0" in printed
