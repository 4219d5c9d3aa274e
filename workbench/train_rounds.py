"""Training on pseudo-demonstrations that keep coming, in rounds (``python -m workbench.cli.train_rounds``, ``make
train-gpu``, ``make campaign``).

The run is a sequence of R rounds. Round 0's pseudo-tasks are generated first (``lerobot-ip-generate`` with
``workers`` processes: the only generation the trainer waits for) and become the training dataset. Then, for
k = 0 … R−1:

* ``lerobot-train`` trains on the training dataset (rounds 0…k) up to step (k+1)·S: round 0 fresh (``start``:
  ``fresh``, ``shipped`` for the package's checkpoint, or a ``pretrained_model`` directory), later rounds by resuming
  the run's last checkpoint with ``--steps`` raised;
* meanwhile, in the background, round k+1 is generated (with the held-out validation set before it during round 0)
  and its append to the training dataset is staged (``pseudo_demos/merge.py``: the old data files are hard-linked, only the
  new ones written);
* after training, the staged append is swapped into place. The old frames keep their files and ``index`` values, so
  the next ``lerobot-train`` extends the frozen encoder's per-frame cache with the new frames only
  (``frame_encodings``) instead of encoding every frame again.

Finally the last checkpoint's action error and context gain on the held-out pseudo-tasks
(``lerobot-ip-action-error``, K=4, N=2, L=10, against its own demonstrations and another task's) and the loss curve
of every checkpoint (``lerobot-ip-loss-curve``). A JSON summary (rounds, tasks, episodes, frames, steps, minutes per
stage, the action error) is printed and written to ``OUT/summary.json``.

Learning rate: ``lerobot-train`` spans the policy's warmup + cosine schedule over ``--steps``; a resume with raised
``--steps`` rebuilds it over the new total at the step reached, so each round ends at zero and the next restarts at
a lower fraction of the peak (a warm restart per round: 1/2, 1/4, 0.15 … of the peak at rounds 1, 2, 3 …).

Layout of ``OUT``::

    state.json          the plan (settings that decide the data and the training) and the stages done, with minutes
    rounds/round-XXX/   round XXX's generated dataset, deleted once it is in the training dataset
    train/              the training dataset (grows each round; its frame-encoding cache beside the data)
    val/                held-out pseudo-tasks (the library's held-out objects), generated once
    run/                the lerobot-train output directory (checkpoints/<step>/pretrained_model, checkpoints/last)
    logs/<stage>.log    what each stage printed
    action_error.json, loss_curve.png, loss_curve.json, summary.json

Resuming: running the same command again continues where it stopped. A stage recorded in ``state.json`` is not
redone (a round whose training finished is not trained again), an interrupted generation resumes shard by shard, an
interrupted training resumes from its last checkpoint, and a half-done append is finished or redone. ``rounds`` may
be raised for a finished run (more rounds follow); the settings of the plan may not change.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from lerobot_instant_policy.pseudo_demos.tasks import FAMILIES

PROG = "python -m workbench.cli.train_rounds"
STATE_FILE = "state.json"
STATE_VERSION = 1
TRAIN_REPO_ID, VAL_REPO_ID = "local/train", "local/val"
EVAL_K, EVAL_N, EVAL_L = 4, 2, 10
MODULES = {
    "lerobot-train": "lerobot.scripts.lerobot_train",
    "lerobot-ip-generate": "lerobot_instant_policy.cli.generate",
    "lerobot-ip-action-error": "lerobot_instant_policy.cli.action_error",
    "lerobot-ip-loss-curve": "lerobot_instant_policy.cli.loss_curve",
    "lerobot-ip-train": "lerobot_instant_policy.cli.train_stream",
}


class TrainRoundsError(ValueError):
    """Bad settings, an output directory holding something else, or a stage that failed."""


@dataclasses.dataclass
class TrainRoundsConfig:
    """What ``python -m workbench.cli.train_rounds`` does (``--config`` JSON keys; command-line flags override them).

    Data: ``rounds`` rounds of ``tasks_per_round`` pseudo-tasks of ``family``, ``demos_per_task`` demonstrations
    each, in groups of ``tasks_per_object_group`` that share their objects, generated in shards of
    ``tasks_per_shard`` tasks by ``workers`` processes; round k draws from seed ``seed + k``. ``generation_config``:
    a ``lerobot-ip-generate`` JSON config the rounds and the validation set start from (cloud source, points per
    cloud, …). ``shared_layout_fractions``: the fraction of one-layout pseudo-tasks (every demonstration of a task in
    one object layout) in each round, entry k for round k and the last entry for every later round, so that a
    curriculum can anneal from the live layout to objects that move between demonstrations; None leaves the
    generation config's fraction. ``layout_shifts``: likewise per round, how far the other tasks' demonstrations move
    the objects from their first demonstration's layout (``DemoConfig.layout_shift``: 0 one layout, 1 an independent
    draw, the paper's setting), for a curriculum that grows the moves; None leaves the generation config's.
    Validation: ``val_tasks`` × ``val_demos_per_task`` held-out pseudo-tasks from ``val_seed`` (with
    ``family`` reach and the defaults, the pseudo-tasks of ``workbench/configs/generate/rung1_reach_val.json``).

    Training: ``steps_per_round`` optimiser steps of ``batch_size`` per round, ``checkpoints_per_round`` checkpoints
    each (the loss curve's points), ``num_workers`` data-loader processes, on ``device``. ``start``: ``fresh`` (a new
    policy with the config's defaults, the shipped model's), ``shipped`` (the package's checkpoint) or a ``pretrained_model`` directory.
    ``policy_overrides`` (``--policy.*`` arguments) are added to the first ``lerobot-train`` call whatever the
    start; resumed rounds keep the run's saved config. ``launcher``: a command put before ``lerobot-train``, e.g.
    ``["accelerate", "launch", "--multi_gpu", "--num_processes=4"]`` for several GPUs.

    Evaluation: ``eval_frames_per_task`` frames of each validation task for the action error, ``loss_curve_samples``
    frames of each dataset for the loss curve.
    """

    out: str = "outputs/train_rounds"
    family: str = "reach"
    rounds: int = 4
    tasks_per_round: int = 200
    demos_per_task: int = 6
    tasks_per_object_group: int = 4
    tasks_per_shard: int = 10
    seed: int = 31
    generation_config: str | None = None
    shared_layout_fractions: list[float] | None = None
    layout_shifts: list[float] | None = None
    val_tasks: int = 24
    val_demos_per_task: int = 4
    val_seed: int = 121
    steps_per_round: int = 1000
    checkpoints_per_round: int = 2
    batch_size: int = 32
    workers: int = 12
    num_workers: int = 2
    device: str = "cuda"
    start: str = "fresh"
    policy_overrides: list[str] = dataclasses.field(default_factory=list)
    launcher: list[str] = dataclasses.field(default_factory=list)
    eval_frames_per_task: int = 4
    loss_curve_samples: int = 96

    def validate(self) -> None:
        positive = ("rounds", "tasks_per_round", "tasks_per_object_group", "tasks_per_shard", "steps_per_round",
                    "checkpoints_per_round", "batch_size", "workers", "eval_frames_per_task", "loss_curve_samples")
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int) or value <= 0:
                raise TrainRoundsError(f"{name} must be a positive integer, got {value!r}")
        if not isinstance(self.num_workers, int) or self.num_workers < 0:
            raise TrainRoundsError(f"num_workers must be a non-negative integer, got {self.num_workers!r}")
        if self.demos_per_task < 2:
            raise TrainRoundsError(f"demos_per_task must be at least 2 (a frame's context is another demonstration "
                                   f"of its task), got {self.demos_per_task}")
        if self.val_tasks < 2:
            raise TrainRoundsError(
                f"val_tasks must be at least 2 (the context swap needs two tasks), got {self.val_tasks}"
            )
        if self.val_demos_per_task < EVAL_N + 1:
            raise TrainRoundsError(f"val_demos_per_task must be at least {EVAL_N + 1} (N={EVAL_N} demonstrations and "
                                   f"a live episode), got {self.val_demos_per_task}")
        if self.checkpoints_per_round > self.steps_per_round:
            raise TrainRoundsError(f"checkpoints_per_round ({self.checkpoints_per_round}) cannot exceed "
                                   f"steps_per_round ({self.steps_per_round})")
        if self.family not in FAMILIES:
            raise TrainRoundsError(f"family must be one of {list(FAMILIES)}, got {self.family!r}")
        if self.seed <= self.val_seed < self.seed + self.rounds:
            raise TrainRoundsError(f"val_seed {self.val_seed} is the seed of a training round "
                                   f"({self.seed} … {self.seed + self.rounds - 1}): choose another")
        if self.start not in ("fresh", "shipped"):
            checkpoint = Path(self.start)
            if not (checkpoint / "config.json").is_file() or not (checkpoint / "model.safetensors").is_file():
                raise TrainRoundsError(f"start must be 'fresh', 'shipped' or a pretrained_model directory (with "
                                       f"config.json and model.safetensors), got {self.start!r}")
        bad = [arg for arg in self.policy_overrides if not arg.startswith("--policy.")]
        if bad:
            raise TrainRoundsError(f"policy_overrides must be --policy.* arguments, got {bad}")
        for name in ("shared_layout_fractions", "layout_shifts"):
            values = getattr(self, name)
            if values is not None and (not values or not all(
                    isinstance(value, (int, float)) and 0.0 <= value <= 1.0 for value in values)):
                raise TrainRoundsError(f"{name} must be a non-empty list of numbers in [0, 1], got {values!r}")
        if self.generation_config is not None and not Path(self.generation_config).is_file():
            raise TrainRoundsError(f"generation_config {self.generation_config} does not exist")

    def plan(self) -> dict:
        """The settings that decide the data and the training: a resumed run must have the same (``rounds`` may grow;
        ``out``, the process counts, ``device``, ``launcher`` and the evaluation sizes may change)."""
        plan = dataclasses.asdict(self)
        for key in ("out", "rounds", "workers", "num_workers", "device", "launcher", "eval_frames_per_task",
                    "loss_curve_samples"):
            plan.pop(key)
        if self.layout_shifts is None:  # as before the setting existed: older runs still resume
            plan.pop("layout_shifts")
        if self.generation_config is not None:
            plan["generation_config"] = json.loads(Path(self.generation_config).read_text())
        return plan

    def shared_layout_fraction(self, number: int) -> float | None:
        """The fraction of one-layout tasks in round ``number`` (None: the generation config's)."""
        return _of_round(self.shared_layout_fractions, number)

    def layout_shift(self, number: int) -> float | None:
        """How far round ``number``'s demonstrations move the objects (None: the generation config's)."""
        return _of_round(self.layout_shifts, number)

    @property
    def save_freq(self) -> int:
        return self.steps_per_round // self.checkpoints_per_round

    @property
    def log_freq(self) -> int:
        return max(1, min(50, self.steps_per_round // 4))


def _of_round(values: list[float] | None, number: int) -> float | None:
    """Entry ``number`` of a per-round schedule, the last for every later round (None: no schedule)."""
    return None if values is None else float(values[min(number, len(values) - 1)])


# ---------------------------------------------------------------------------------------------------- paths
class Layout:
    """The paths of a run under ``out`` (module docstring)."""

    def __init__(self, out: str | Path):
        self.out = Path(out).absolute()
        self.state = self.out / STATE_FILE
        self.train = self.out / "train"
        self.val = self.out / "val"
        self.run = self.out / "run"
        self.logs = self.out / "logs"
        self.hf_cache = self.out / ".hf_datasets_cache"
        self.last_checkpoint = self.run / "checkpoints" / "last"

    def round(self, number: int) -> Path:
        return self.out / "rounds" / f"round-{number:03d}"

    def latest_checkpoint(self) -> Path | None:
        """The checkpoint to resume: ``checkpoints/last``, or the latest numbered one when ``last`` is missing (a run
        killed between saving a checkpoint and pointing ``last`` at it); None before the first."""
        complete = [path for path in (self.run / "checkpoints").glob("*")
                    if (path / "pretrained_model" / "train_config.json").is_file()
                    and (path / "training_state" / "training_step.json").is_file()]
        if self.last_checkpoint in complete:
            return self.last_checkpoint
        return max((path for path in complete if path.name.isdigit()), key=lambda path: int(path.name), default=None)

    def trained_steps(self) -> int:
        """The step of the checkpoint to resume (0 without one)."""
        checkpoint = self.latest_checkpoint()
        if checkpoint is None:
            return 0
        return int(json.loads((checkpoint / "training_state" / "training_step.json").read_text())["step"])


def program(name: str, launcher: list[str] | None = None) -> list[str]:
    """How to start the command ``name``: its console script beside this Python (a virtual environment's ``bin/``),
    else ``python -m`` its module (an install without scripts beside the interpreter, such as ``../shared/gpu``'s);
    after ``launcher`` (e.g. ``accelerate launch ...``), which takes a script path or ``-m module``."""
    script = Path(sys.executable).parent / name
    if launcher:
        return [*launcher, str(script)] if script.is_file() else [*launcher, "-m", MODULES[name]]
    return [str(script)] if script.is_file() else [sys.executable, "-m", MODULES[name]]


# ---------------------------------------------------------------------------------------------------- commands
def generate_command(config: TrainRoundsConfig, out: Path, num_tasks: int, demos_per_task: int, seed: int,
                     object_split: str, resume_flag: str | None = None,
                     shared_layout_fraction: float | None = None, layout_shift: float | None = None) -> list[str]:
    """``lerobot-ip-generate`` of ``num_tasks`` × ``demos_per_task`` pseudo-tasks of the run's family into ``out``;
    ``resume_flag``: ``--resume`` or ``--overwrite`` for a directory an interrupted generation left;
    ``shared_layout_fraction``: the fraction of one-layout tasks, ``layout_shift`` how far the others move their
    objects (None: the generation config's)."""
    command = program("lerobot-ip-generate")
    if config.generation_config is not None:
        command += ["--config", str(Path(config.generation_config).absolute())]
    command += [
        "--out", str(out), "--repo-id", f"local/{out.name}", "--family", config.family,
        "--num-tasks", str(num_tasks), "--demos-per-task", str(demos_per_task),
        "--tasks-per-object-group", str(config.tasks_per_object_group),
        "--tasks-per-shard", str(config.tasks_per_shard), "--seed", str(seed), "--object-split", object_split,
        "--workers", str(config.workers), "--no-progress",
    ]
    if shared_layout_fraction is not None:
        command += ["--shared-layout-fraction", str(shared_layout_fraction)]
    if layout_shift is not None:
        command += ["--layout-shift", str(layout_shift)]
    return command + ([resume_flag] if resume_flag else [])


def round_command(config: TrainRoundsConfig, layout: Layout, number: int, resume_flag: str | None = None) -> list[str]:
    return generate_command(config, layout.round(number), config.tasks_per_round, config.demos_per_task,
                            config.seed + number, "train", resume_flag, config.shared_layout_fraction(number),
                            config.layout_shift(number))


def val_command(config: TrainRoundsConfig, layout: Layout, resume_flag: str | None = None) -> list[str]:
    return generate_command(config, layout.val, config.val_tasks, config.val_demos_per_task, config.val_seed,
                            "held_out", resume_flag)


def train_command(config: TrainRoundsConfig, layout: Layout, number: int, resume_from: Path | None) -> list[str]:
    """``lerobot-train`` up to step (number+1)·S: resuming the checkpoint ``resume_from``, or the run's first call."""
    steps = f"--steps={(number + 1) * config.steps_per_round}"
    command = program("lerobot-train", config.launcher)
    if resume_from is not None:
        train_config = resume_from / "pretrained_model" / "train_config.json"
        return command + [f"--config_path={train_config}", "--resume=true", steps]
    if config.start == "fresh":
        command += ["--policy.type=instant_policy"]
    else:
        checkpoint = SHIPPED_CHECKPOINT if config.start == "shipped" else Path(config.start).absolute()
        command += [f"--policy.path={checkpoint}"]
    return command + [
        f"--policy.device={config.device}", *config.policy_overrides,
        f"--dataset.repo_id={TRAIN_REPO_ID}", f"--dataset.root={layout.train}", steps,
        f"--batch_size={config.batch_size}", f"--num_workers={config.num_workers}", f"--log_freq={config.log_freq}",
        f"--save_freq={config.save_freq}", f"--seed={config.seed}", "--wandb.enable=false", "--job_name=train_rounds",
        f"--output_dir={layout.run}",
    ]


def action_error_command(config: TrainRoundsConfig, layout: Layout) -> list[str]:
    checkpoint = layout.latest_checkpoint() or layout.last_checkpoint
    return program("lerobot-ip-action-error") + [
        "--policy-path", str(checkpoint / "pretrained_model"), "--root", str(layout.val),
        "--repo-id", VAL_REPO_ID, "--tasks", str(config.val_tasks),
        "--frames-per-task", str(config.eval_frames_per_task), "--K", str(EVAL_K), "--N", str(EVAL_N),
        "--L", str(EVAL_L), "--no-untrained", "--json", "--device", config.device,
    ]


def loss_curve_command(config: TrainRoundsConfig, layout: Layout) -> list[str]:
    return program("lerobot-ip-loss-curve") + [
        "--run", str(layout.run), "--train-root", str(layout.train), "--val-root", str(layout.val),
        "--train-repo-id", TRAIN_REPO_ID, "--val-repo-id", VAL_REPO_ID, "--samples", str(config.loss_curve_samples),
        "--device", config.device, "--out", str(layout.out / "loss_curve.png"),
    ]


# ---------------------------------------------------------------------------------------------------- stages
@dataclasses.dataclass
class Stage:
    """One unit of work, recorded in the state by ``name`` once done: a subprocess ``command`` (built when the stage
    starts, from what is on disk) whose output goes to ``logs/<name>.log``, or an in-process ``action``.
    ``describe``: one line for the progress log and the dry run."""

    name: str
    describe: str
    command: Callable[[], list[str]] | None = None
    action: Callable[[], None] | None = None
    done: Callable[[], bool] = lambda: False  # finished on disk though not recorded (interrupted before recording)
    stdout_file: str | None = None  # keep the subprocess's stdout apart (a JSON result) in this file under OUT


@dataclasses.dataclass
class Step:
    """``foreground`` while ``background`` stages run one after another beside it."""

    foreground: Stage
    background: list[Stage] = dataclasses.field(default_factory=list)


def generated(root: Path) -> bool:
    """Whether ``root`` holds a finished ``lerobot-ip-generate`` dataset (merged, no shards left)."""
    return (root / "meta" / "info.json").is_file() and not (root / ".shards").exists()


def resume_flag(root: Path) -> str | None:
    """How to call ``lerobot-ip-generate`` on ``root``: ``--resume`` after an interruption that left shards,
    ``--overwrite`` for other leftovers, nothing for a new directory."""
    if (root / ".shards" / "plan.json").is_file():
        return "--resume"
    return "--overwrite" if root.exists() else None


def holds_tasks_of(train: Path, round_root: Path) -> bool:
    """Whether the training dataset already has the tasks of the round dataset at ``round_root``."""
    import pandas as pd

    if not (train / "meta" / "tasks.parquet").is_file() or not (round_root / "meta" / "tasks.parquet").is_file():
        return False
    tasks = set(pd.read_parquet(train / "meta" / "tasks.parquet").index)
    return set(pd.read_parquet(round_root / "meta" / "tasks.parquet").index) <= tasks


def plan_steps(config: TrainRoundsConfig, layout: Layout, dry_run: bool = False) -> list[Step]:
    """The stages of the whole run in order (module docstring). With ``dry_run`` the commands are those of a run
    from scratch; otherwise each is built when its stage starts, from what an earlier invocation left on disk."""
    from lerobot_instant_policy.pseudo_demos import merge
    from lerobot_instant_policy.pseudo_demos.generation import DEMOS_FILE, TASKS_FILE

    def generate_round(number: int) -> Stage:
        root = layout.round(number)
        return Stage(
            f"generate-{number:03d}", f"generate round {number}: {config.tasks_per_round} pseudo-tasks × "
            f"{config.demos_per_task} demonstrations of '{config.family}' (seed {config.seed + number}) into {root}",
            command=lambda: round_command(config, layout, number, None if dry_run else resume_flag(root)),
            done=lambda: generated(root),
        )

    def stage_append(number: int) -> Stage:
        root = layout.round(number)
        return Stage(
            f"stage-append-{number:03d}", f"stage round {number}'s append to {layout.train} (in process: "
            "pseudo_demos/merge.py prepare_append)",
            action=lambda: merge.prepare_append(layout.train, TRAIN_REPO_ID, [root], [f"local/{root.name}"],
                                                (TASKS_FILE, DEMOS_FILE)),
        )

    def append(number: int) -> Stage:
        root = layout.round(number)

        def run() -> None:
            merge.finish_append(layout.train)
            if not holds_tasks_of(layout.train, root):
                merge.append_datasets(layout.train, TRAIN_REPO_ID, [root], [f"local/{root.name}"],
                                      (TASKS_FILE, DEMOS_FILE))
            shutil.rmtree(root)
            if not any(root.parent.iterdir()):
                root.parent.rmdir()

        # The round's directory exists from its generation on and is deleted once it is in the training dataset.
        return Stage(f"append-{number:03d}", f"append round {number} to the training dataset {layout.train} (in "
                     "process: pseudo_demos/merge.py finish_append, or append_datasets when nothing was staged)", action=run,
                     done=lambda: not root.exists())

    def train(number: int) -> Stage:
        target = (number + 1) * config.steps_per_round

        def command() -> list[str]:
            resume_from = layout.latest_checkpoint()
            if resume_from is None and layout.run.exists():
                shutil.rmtree(layout.run)  # a first call killed before its first checkpoint: lerobot-train restarts
            return train_command(config, layout, number, resume_from)

        start = "resume the last checkpoint" if number else f"start: {config.start}"
        return Stage(
            f"train-{number:03d}", f"train round {number}: lerobot-train to step {target} on rounds 0…{number} "
            f"({start})", command=command if not dry_run else
            (lambda: train_command(config, layout, number, layout.last_checkpoint if number else None)),
            done=lambda: layout.trained_steps() >= target,
        )

    final_step = config.rounds * config.steps_per_round
    steps = [Step(generate_round(0)), Step(append(0))]
    for number in range(config.rounds):
        background = [Stage("val", f"generate the validation set: {config.val_tasks} held-out pseudo-tasks × "
                            f"{config.val_demos_per_task} (seed {config.val_seed}) into {layout.val}",
                            command=lambda: val_command(config, layout, None if dry_run else resume_flag(layout.val)),
                            done=lambda: generated(layout.val))] if number == 0 else []
        if number + 1 < config.rounds:
            background += [generate_round(number + 1), stage_append(number + 1)]
        steps.append(Step(train(number), background))
        if number + 1 < config.rounds:
            steps.append(Step(append(number + 1)))
    steps.append(Step(Stage(f"action-error-{final_step:06d}", f"action error and context gain of step {final_step} on "
                            "the validation set", command=lambda: action_error_command(config, layout),
                            stdout_file="action_error.json")))
    steps.append(Step(Stage(f"loss-curve-{final_step:06d}", "loss curve of every checkpoint",
                            command=lambda: loss_curve_command(config, layout), stdout_file="loss_curve_summary.json")))
    return steps


# ---------------------------------------------------------------------------------------------------- running
class Runner:
    """Runs the steps, records each finished stage and its minutes in ``state.json``, and stops every process it
    started (by its process group) when interrupted or when a stage fails."""

    def __init__(self, config: TrainRoundsConfig, layout: Layout, state: dict):
        self.config, self.layout, self.state = config, layout, state
        self.started, self.wall_before = time.perf_counter(), state.get("wall_minutes", 0.0)
        self.lock = threading.Lock()
        self.processes: set[subprocess.Popen] = set()
        self.stopping = threading.Event()
        self.env = {**os.environ, "HF_DATASETS_CACHE": str(layout.hf_cache)}
        self.env.setdefault("HF_HUB_OFFLINE", "1")

    def log(self, message: str) -> None:
        print(f"[{PROG} {time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)

    def record(self, name: str, minutes: float) -> None:
        with self.lock:
            self.state["stages"][name] = round(minutes, 3)
            self.state["wall_minutes"] = round(self.wall_before + (time.perf_counter() - self.started) / 60, 3)
            write_state(self.layout, self.state)

    def run_stage(self, stage: Stage) -> None:
        if stage.name in self.state["stages"] or self.stopping.is_set():
            return
        if stage.done():
            self.log(f"{stage.name}: already finished on disk")
            self.record(stage.name, 0.0)
            return
        self.log(stage.describe)
        started = time.perf_counter()
        if stage.action is not None:
            stage.action()
        else:
            self.run_command(stage)
        self.record(stage.name, (time.perf_counter() - started) / 60)

    def run_command(self, stage: Stage) -> None:
        command = stage.command()
        self.layout.logs.mkdir(parents=True, exist_ok=True)
        log_path = self.layout.logs / f"{stage.name}.log"
        env = self.env if not stage.name.startswith(("generate", "val")) else {**self.env, "OMP_NUM_THREADS": "1"}
        with contextlib.ExitStack() as files:
            log = files.enter_context(open(log_path, "w"))
            log.write(shlex.join(command) + "\n")
            log.flush()
            stdout = files.enter_context(open(self.layout.out / stage.stdout_file, "w")) if stage.stdout_file else log
            with self.lock:  # no process starts once stop_processes has begun
                if self.stopping.is_set():
                    raise TrainRoundsError(f"stage {stage.name} not started: the run is stopping")
                process = subprocess.Popen(command, stdout=stdout, stderr=log, env=env, start_new_session=True)
                self.processes.add(process)
            try:
                code = process.wait()
            finally:
                with self.lock:
                    self.processes.discard(process)
        if code != 0:
            tail = "".join(log_path.read_text().splitlines(keepends=True)[-15:])
            raise TrainRoundsError(f"stage {stage.name} failed (exit code {code}); its log {log_path} ends:\n{tail}")
        if stage.stdout_file:
            path = self.layout.out / stage.stdout_file
            path.write_text(json.dumps(json_result(path.read_text()), indent=2))

    def stop_processes(self) -> None:
        """Terminate every process group this runner started (the commands and their workers)."""
        with self.lock:
            self.stopping.set()
            processes = list(self.processes)
        for process in processes:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGTERM)
        for process in processes:
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGKILL)

    def run_step(self, step: Step) -> None:
        """Run ``step.background`` in a thread beside ``step.foreground``. An error or an interruption of the foreground
        stops every process at once; an error of the background is raised once the foreground is over."""
        errors: list[BaseException] = []

        def background() -> None:
            try:
                for stage in step.background:
                    self.run_stage(stage)
            except BaseException as error:  # raised by the main thread once the foreground is over
                errors.append(error)

        if step.foreground.name.startswith("train") and step.foreground.name not in self.state["stages"]:
            self.clear_dataset_cache()
        thread = threading.Thread(target=background, daemon=True)
        thread.start()
        try:
            self.run_stage(step.foreground)
            while thread.is_alive():
                thread.join(timeout=1.0)
        except BaseException:
            self.stop_processes()
            thread.join()
            raise
        if errors:
            raise errors[0]

    def clear_dataset_cache(self) -> None:
        """Drop the Arrow copies the ``datasets`` library made of the previous rounds' data (one whole copy of the
        training dataset per load of a grown dataset); nothing else runs between rounds."""
        if self.layout.hf_cache.exists():
            shutil.rmtree(self.layout.hf_cache)


def json_result(text: str) -> dict:
    """The JSON object a command printed last on its stdout (after whatever the libraries it loads printed)."""
    starts = [0] if text.startswith("{") else []
    starts += [index + 1 for index in range(len(text)) if text.startswith("\n{", index)]
    for start in starts:
        try:
            return json.loads(text[start:])
        except ValueError:
            continue
    raise TrainRoundsError(f"no JSON result in the output: {text[-500:]!r}")


# ---------------------------------------------------------------------------------------------------- state
def read_state(config: TrainRoundsConfig, layout: Layout) -> dict:
    """The state of the run in ``layout.out``: a new one for a missing or empty directory, the saved one when its
    plan is ``config``'s; ``TrainRoundsError`` for a directory that holds anything else."""
    plan = config.plan()
    if layout.state.is_file():
        try:
            state = json.loads(layout.state.read_text())
        except ValueError as error:
            raise TrainRoundsError(f"{layout.state} is not readable JSON: {error}") from error
        if state.get("version") != STATE_VERSION or not isinstance(state.get("stages"), dict):
            raise TrainRoundsError(f"{layout.state} is not a {PROG} state file (version {STATE_VERSION})")
        if state.get("plan") != plan:
            saved = state.get("plan") or {}
            changed = sorted(key for key in saved.keys() | plan.keys() if saved.get(key) != plan.get(key))
            raise TrainRoundsError(
                f"{layout.out} holds another run (its state.json differs in {changed}); pass another --out, or delete "
                f"{layout.out} to start over"
            )
        return state
    if layout.out.exists() and any(layout.out.iterdir()):
        raise TrainRoundsError(f"{layout.out} is not empty and holds no {STATE_FILE}: pass a new or empty --out")
    return {"version": STATE_VERSION, "plan": plan, "stages": {}, "wall_minutes": 0.0}


def write_state(layout: Layout, state: dict) -> None:
    """Write ``state.json`` atomically (a temporary file renamed over it)."""
    layout.out.mkdir(parents=True, exist_ok=True)
    tmp = layout.state.with_name(STATE_FILE + ".tmp")
    tmp.write_text(json.dumps(state, indent=1))
    tmp.replace(layout.state)


def summary(config: TrainRoundsConfig, layout: Layout, state: dict) -> dict:
    """What the run produced: sizes, steps, minutes per stage (background stages overlap training) and the wall time
    of all invocations together, the action error and the loss curve's figures."""
    info = json.loads((layout.train / "meta" / "info.json").read_text())
    action_error = json.loads((layout.out / "action_error.json").read_text())
    loss_curve = json.loads((layout.out / "loss_curve_summary.json").read_text())
    default = action_error["settings"][0]
    return {
        "out": str(layout.out),
        "family": config.family,
        "start": config.start,
        "device": config.device,
        "rounds": config.rounds,
        "tasks": config.rounds * config.tasks_per_round,
        "episodes": int(info["total_episodes"]),
        "frames": int(info["total_frames"]),
        "steps": layout.trained_steps(),
        "batch_size": config.batch_size,
        "checkpoint": str((layout.latest_checkpoint() or layout.last_checkpoint) / "pretrained_model"),
        "minutes": {**state["stages"], "wall": state.get("wall_minutes", 0.0)},
        "action_error": {"K": default["K"], "N": default["N"], "L": default["L"],
                         "translation_mm": default["translation_mm"], "rotation_deg": default["rotation_deg"],
                         "gripper_accuracy": default["gripper_accuracy"],
                         "hold_translation_mm": action_error["hold"]["translation_mm"],
                         "swap_translation_mm": action_error["swap"]["translation_mm"]},
        "context_gain": action_error["context_gain"],
        "action_error_json": str(layout.out / "action_error.json"),
        "loss_curve": {"png": loss_curve["png"], "json": loss_curve["json"], "best_val": loss_curve["best_val"],
                       "last": loss_curve["curve"][-1]},
    }


def dry_run(config: TrainRoundsConfig, layout: Layout) -> None:
    """Print every stage of a run from scratch and its command (``&`` marks the stages run beside the one before)."""
    for step in plan_steps(config, layout, dry_run=True):
        for stage, prefix in [(step.foreground, "")] + [(stage, "&   ") for stage in step.background]:
            print(f"{prefix}# {stage.name}: {stage.describe}")
            if stage.command is not None:
                print(prefix + shlex.join(stage.command()))


def run(config: TrainRoundsConfig) -> dict:
    """Run (or resume) every stage; return the summary."""
    layout = Layout(config.out)
    state = read_state(config, layout)
    write_state(layout, state)
    runner = Runner(config, layout, state)
    trained = layout.trained_steps()
    if trained > config.rounds * config.steps_per_round:
        raise TrainRoundsError(
            f"{layout.out} has trained {trained} steps, more than {config.rounds} rounds of {config.steps_per_round}: "
            f"pass --rounds {math.ceil(trained / config.steps_per_round)} or more"
        )
    for step in plan_steps(config, layout):
        runner.run_step(step)
    runner.clear_dataset_cache()
    result = summary(config, layout, state)
    (layout.out / "summary.json").write_text(json.dumps(result, indent=2))
    return result
