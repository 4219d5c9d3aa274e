"""The standing training run: one command continues the run from its last save, trains on the rolling pool of encoded
fresh pseudo-tasks to a wall-clock deadline, validates the last save on the two held-out sets, and leaves it as the
run's new start, the best save kept apart for shipping, and a point on the scaling curve.

``python -m workbench.cli.standing run --hours 2.5`` (here, on the CPU, under ``nice``), or on a GPU lease
``workbench/scripts/gpu_standing.sh`` (``run --device cuda --generator-device cpu ... --out DIR``) and then here
``python -m workbench.cli.standing accept FOLDER``. A run:

1. starts from the last save, ``checkpoints/stream/last/`` (LeRobot's ``pretrained_model/`` and ``training_state/``,
   kept compactly: :func:`write_compact`), resumed with ``lerobot-ip-train --resume=true``, its optimizer first
   rebuilding the moments the compact save leaves out (``moment_rebuild_steps`` at learning rate 0,
   :mod:`lerobot_instant_policy.training.optimizer`); at the very first start from ``--start`` (a LeRobot step
   checkpoint, resumed the same way) or else the shipped checkpoint (its weights, a fresh optimizer);
2. trains with ``lerobot-ip-train --pool`` (:mod:`lerobot_instant_policy.training.task_pool`) on the stream of
   ``stream_config`` with the run's seed, LeRobot saving every ``save_freq`` steps, while the two validation sets
   (``VALIDATION_CONFIGS``: held-out objects moved between demonstrations, or kept in one layout) are generated
   beside it unless present;
3. at ``deadline_s − validate_s`` stops training (a kill loses at most the steps since the last save) and takes its
   last complete save (one with the pool's state, written last), which it validates with ``lerobot-ip-action-error``
   (K = 4, N = 2, L = 10, ``val_tasks`` × ``val_frames_per_task`` frames) on both sets, and with ``average_decay``
   the moving average of its weights too (:func:`validate_average`);
4. keeps it (:func:`keep`): the save, compacted, replaces ``checkpoints/stream/last/`` whether or not it is better
   (a metric may dip before it improves), its weights (or their average, where that validated closer on both sets:
   :func:`readout`) replace ``checkpoints/stream/best/`` only when closer than the best's to the actions, relative to
   holding still, on both sets (the point estimates), and its point (the raw weights') joins
   ``docs/scaling_curve.{json,png}`` (the figures with their 95% intervals over tasks, drawn as error bars).
   ``standing.json`` in the save holds every run so far: samples and distinct tasks (this run's and in all), the
   pool's rates and uses per task, the figures with their intervals, the per-task errors behind them and, once a
   best is kept, the paired difference from the best on each set (``against_best``), so a reader can tell a real
   change from the noise of a few validation tasks;
5. compares the save with the shipped checkpoint the same way (``against_shipped``: :func:`shipped_validation`
   validates the shipped checkpoint once on the same frames and caches its errors in ``shipped.json`` beside the
   saves) and records whether the best save now beats the shipped checkpoint on both sets (``best_beats_shipped``):
   the condition for step 5 of docs/training.md, the suite and MetaWorld's test splits (``make results-candidate``).

With ``--out`` the save and its record are packed into ``OUT`` instead (``save.tar`` and ``standing.json``, two
files), for ``accept`` to keep here.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from lerobot.optim.optimizers import OPTIMIZER_STATE
from safetensors.torch import save_file

from lerobot_instant_policy.evaluation.action_error import PAIRED_KEYS, ActionErrorError, paired_ratio_difference
from lerobot_instant_policy.evaluation.manifest import checkpoint_fingerprint
from lerobot_instant_policy.replay.timing import TIMING_MODEL
from lerobot_instant_policy.training.weight_average import AVERAGE_FILE, write_averaged_model

PROG = "python -m workbench.cli.standing"
EVAL_K, EVAL_N, EVAL_L = 4, 2, 10  # the validation's setting of lerobot-ip-action-error
MODULES = {
    "lerobot-ip-generate": "lerobot_instant_policy.cli.generate",
    "lerobot-ip-action-error": "lerobot_instant_policy.cli.action_error",
    "lerobot-ip-train": "lerobot_instant_policy.cli.train_stream",
}
SHIPPED = Path("lerobot_instant_policy/assets/checkpoints/instant_policy")
STANDING = Path("checkpoints/stream")
CURVE_FILE = Path("docs/scaling_curve.json")
VALIDATION_CONFIGS = {
    "moved": "configs/generate/val_moved_objects.json",
    "one_layout": "configs/generate/val_one_layout.json",
}
RESULTS_DIR = "results"  # under a validation root: one checkpoint's results on its sets, by fingerprint
RECORD = "standing.json"
SHIPPED_RECORD = "shipped.json"
SAVE_TAR = "save.tar"
POOL_STATE = "training_state/task_pool.json"  # written after the rest of a save: its presence marks a complete one
MODEL_DIR, STATE_DIR = "pretrained_model", "training_state"
AVERAGE_MODEL_DIR = "pretrained_model_average"  # a save's moving average as a pretrained_model, when it keeps one
COMPACT_OMITS = (OPTIMIZER_STATE, AVERAGE_FILE)  # what a kept save leaves out of training_state/ (write_compact)


# the validation's replay start (StandingConfig's fields of that name): part of a cached result's key where given
REPLAY_OPTIONS = ("replay_init_strength", "replay_per_object", "replay_anchored")


class StandingError(RuntimeError):
    """A run that could not train, save or validate (the message says which step and shows its output)."""


def program(name: str) -> list[str]:
    """How to start the command ``name``: its console script beside this Python (a virtual environment's ``bin/``),
    else ``python -m`` its module (an install without scripts beside the interpreter, such as ``../shared/gpu``'s)."""
    script = Path(sys.executable).parent / name
    return [str(script)] if script.is_file() else [sys.executable, "-m", MODULES[name]]


def json_result(text: str) -> dict:
    """The JSON object a command printed last on its stdout (after whatever the libraries it loads printed)."""
    starts = [0] if text.startswith("{") else []
    starts += [index + 1 for index in range(len(text)) if text.startswith("\n{", index)]
    for start in starts:
        try:
            return json.loads(text[start:])
        except ValueError:
            continue
    raise StandingError(f"no JSON result in the output: {text[-500:]!r}")


@dataclass
class StandingConfig:
    """One run of the standing training (module docstring). ``prior_samples`` / ``prior_tasks``: what the start
    (``--start``, before any standing save exists) had already seen. ``base_lr`` / ``weight_decay``: a study arm's
    recipe, written into the resumed optimizer and scheduler (None: as the save holds them; the schedule's shape and
    step go on unchanged, only its peak rate changes). ``average_decay``: keep a moving average of the weights
    (``lerobot-ip-train --average.decay``; None: none), validated beside the raw weights. ``device``: where the update
    runs; ``generator_device``: where the pool's generators render and encode (None: ``device``; on a GPU machine its
    CPU cores can feed the pool instead, the GPU left to the update). ``lerobot_args``: more ``lerobot-train`` flags.
    ``replay_init_strength`` / ``replay_per_object`` / ``replay_anchored``: validate every checkpoint started from the
    replay of its demonstrations, so planned (``lerobot-ip-action-error --replay-init-strength``; None: as the
    checkpoint's config says). ``moment_rebuild_steps``: the steps at learning rate 0 with which a resumed
    optimizer that a compact save left without moments rebuilds them first."""

    deadline_s: float = 9000.0
    validate_s: float = 420.0
    work: str = "outputs/standing"
    out: str | None = None
    start: str | None = None
    stream_config: str = "configs/generate/stream_bounded_mixed.json"
    seed: int = 5000
    device: str = "cpu"
    generator_device: str | None = None
    batch_size: int = 8
    optimizer_lr: float = 2e-4
    samples_per_task: int = 8
    tasks_per_render: int = 1
    surface_samples: int = 4096
    capacity: int = 1000
    min_tasks: int = 16
    generators: int = 1
    generator_threads: int = 1
    train_threads: int = 1
    save_freq: int = 500
    log_freq: int = 50
    nice: int = 10
    val_tasks: int = 96
    val_frames_per_task: int = 4
    val_workers: int = 1
    prior_samples: int = 0
    prior_tasks: int = 0
    base_lr: float | None = None
    weight_decay: float | None = None
    average_decay: float | None = 0.99975
    lerobot_args: list[str] = field(default_factory=list)
    replay_init_strength: float | None = None
    replay_per_object: bool | None = None
    replay_anchored: bool | None = None
    moment_rebuild_steps: int = 100

    def validate(self) -> None:
        if not 0 < self.validate_s < self.deadline_s:
            raise ValueError(f"validate_s must lie in (0, deadline_s = {self.deadline_s}), got {self.validate_s}")
        for name in ("batch_size", "samples_per_task", "tasks_per_render", "surface_samples", "capacity", "min_tasks",
                     "generators",
                     "generator_threads", "train_threads", "save_freq", "log_freq", "val_tasks",
                     "val_frames_per_task", "val_workers"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.optimizer_lr <= 0:
            raise ValueError(f"optimizer_lr must be positive, got {self.optimizer_lr}")
        if self.base_lr is not None and self.base_lr <= 0:
            raise ValueError(f"base_lr must be positive, got {self.base_lr}")
        if self.weight_decay is not None and self.weight_decay < 0:
            raise ValueError(f"weight_decay must be non-negative, got {self.weight_decay}")
        if self.average_decay is not None and not 0 < self.average_decay < 1:
            raise ValueError(f"average_decay must lie in (0, 1), got {self.average_decay}")
        if self.replay_init_strength is not None and not 0 < self.replay_init_strength <= 1:
            raise ValueError(f"replay_init_strength must lie in (0, 1], got {self.replay_init_strength}")
        if self.moment_rebuild_steps < 0:
            raise ValueError(f"moment_rebuild_steps must be non-negative, got {self.moment_rebuild_steps}")


# ---------------------------------------------------------------------------------------------------- saves
def complete_saves(train_dir: Path) -> list[Path]:
    """LeRobot's step checkpoints under ``train_dir/checkpoints`` that were written to the end, oldest first."""
    saves = [path.parent.parent for path in (train_dir / "checkpoints").glob(f"[0-9]*/{POOL_STATE}")]
    return sorted(saves, key=lambda path: int(path.name))


def read_record(save: Path) -> dict:
    """The ``standing.json`` of a save: ``{"runs": [...]}`` (empty for a save of no standing run)."""
    path = save / RECORD
    return json.loads(path.read_text()) if path.is_file() else {"runs": []}


def step_of(save: Path) -> int:
    return int(json.loads((save / STATE_DIR / "training_step.json").read_text())["step"])


def start_save(config: StandingConfig, standing: Path = STANDING) -> Path | None:
    """The save a run resumes: the standing run's last, else ``config.start``; None: the shipped checkpoint's weights
    with a fresh optimizer."""
    last = standing / "last"
    if (last / STATE_DIR).is_dir():
        return last
    if config.start:
        start = Path(config.start)
        if not (start / MODEL_DIR).is_dir() or not (start / STATE_DIR).is_dir():
            raise ValueError(f"--start must be a LeRobot step checkpoint (pretrained_model/ and training_state/): "
                             f"{start}")
        return start
    return None


def train_command(config: StandingConfig, resume_from: Path | None, train_dir: Path) -> list[str]:
    stream = [f"--stream.config={config.stream_config}", f"--stream.seed={config.seed}",
              f"--stream.samples_per_task={config.samples_per_task}",
              f"--stream.tasks_per_render={config.tasks_per_render}",
              f"--stream.surface_samples={config.surface_samples}", "--pool",
              f"--pool.capacity={config.capacity}", f"--pool.min_tasks={config.min_tasks}",
              f"--pool.generators={config.generators}", f"--pool.generator_threads={config.generator_threads}",
              f"--pool.device={config.generator_device or config.device}"]
    if resume_from is not None:
        start = [f"--config_path={resume_from / MODEL_DIR / 'train_config.json'}", "--resume=true",
                 f"--batch_size={config.batch_size}",  # a resumed config keeps the batch it was saved with
                 f"--optimizer.moment_rebuild_steps={config.moment_rebuild_steps}"]
    else:
        start = [f"--policy.path={SHIPPED}", f"--policy.optimizer_lr={config.optimizer_lr}",
                 "--policy.push_to_hub=false", f"--batch_size={config.batch_size}", "--steps=100000000",
                 "--wandb.enable=false", "--num_workers=0"]
    return [*program("lerobot-ip-train"), *stream, *start, f"--policy.device={config.device}",
            f"--output_dir={train_dir}", f"--save_freq={config.save_freq}", f"--log_freq={config.log_freq}",
            *([f"--average.decay={config.average_decay}"] if config.average_decay is not None else []),
            *config.lerobot_args]


def staged_start(train_dir: Path, step: int) -> Path:
    """Where a run's resumed save is staged as a step checkpoint of ``train_dir`` (LeRobot saves after it)."""
    return train_dir / "checkpoints" / f"{step:09d}"


def _stage_resume(save: Path, train_dir: Path, base_lr: float | None = None,
                  weight_decay: float | None = None) -> Path:
    """``save`` copied as a step checkpoint of ``train_dir`` (where LeRobot resumes it and saves after it), with a
    study arm's ``base_lr`` / ``weight_decay`` (None: unchanged) written where a resume reads them: the scheduler's
    ``base_lrs`` (its lr is ``base_lr`` × the schedule's factor at the step) and the optimizer's param groups (their
    ``lr`` scaled alike, ``initial_lr``, ``weight_decay``) and the saved train config (so later resumes keep them).
    A compact save's missing moments are staged as an empty optimizer state, which LeRobot loads as a fresh one."""
    staged = staged_start(train_dir, step_of(save))
    for part in (MODEL_DIR, STATE_DIR):
        shutil.copytree(save / part, staged / part)
    if not (staged / STATE_DIR / OPTIMIZER_STATE).is_file():
        save_file({}, str(staged / STATE_DIR / OPTIMIZER_STATE))
    if base_lr is None and weight_decay is None:
        return staged
    scheduler_path = staged / STATE_DIR / "scheduler_state.json"
    scheduler = json.loads(scheduler_path.read_text())
    groups_path = staged / STATE_DIR / "optimizer_param_groups.json"
    groups = json.loads(groups_path.read_text())
    config_path = staged / MODEL_DIR / "train_config.json"
    train_config = json.loads(config_path.read_text())
    if base_lr is not None:
        for group, old_base in zip(groups, scheduler["base_lrs"], strict=True):
            group["lr"] *= base_lr / old_base
            group["initial_lr"] = base_lr
        scheduler["base_lrs"] = [base_lr] * len(scheduler["base_lrs"])
        scheduler["_last_lr"] = [group["lr"] for group in groups]
        train_config["optimizer"]["lr"] = base_lr
        train_config["policy"]["optimizer_lr"] = base_lr
    if weight_decay is not None:
        for group in groups:
            group["weight_decay"] = weight_decay
        train_config["optimizer"]["weight_decay"] = weight_decay
        train_config["policy"]["optimizer_weight_decay"] = weight_decay
    scheduler_path.write_text(json.dumps(scheduler, indent=4))
    groups_path.write_text(json.dumps(groups, indent=4))
    config_path.write_text(json.dumps(train_config, indent=4))
    return staged


# ---------------------------------------------------------------------------------------------------- validation
def validation_sets(config: StandingConfig, root: Path) -> dict[str, subprocess.Popen | None]:
    """Start generating each validation set missing under ``root`` (None for those already there), each process's
    output to ``root/<name>.log``: a pipe nobody reads until the end fills and stops the generator mid-set."""
    processes = {}
    root.mkdir(parents=True, exist_ok=True)
    for name, preset in VALIDATION_CONFIGS.items():
        if (root / name / "meta" / "info.json").is_file():
            processes[name] = None
            continue
        command = program("lerobot-ip-generate") + [
            "--config", preset, "--out", str(root / name), "--repo-id", f"local/{name}", "--num-tasks",
            str(config.val_tasks), "--workers", str(config.val_workers), "--no-progress", "--overwrite"]
        with open(root / f"{name}.log", "w") as log:
            processes[name] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                               env={**os.environ, "OMP_NUM_THREADS": "1"})
    return processes


def wait_for(generating: dict[str, subprocess.Popen | None], root: Path) -> None:
    """Wait for :func:`validation_sets`' processes under ``root``; ``StandingError`` with the tail of its log where
    one failed."""
    for name, process in generating.items():
        if process is not None and process.wait() != 0:
            log = (root / f"{name}.log").read_text()
            raise StandingError(f"generating the {name} validation set failed: {log[-2000:]}")


def figures(result: dict) -> dict:
    """Translation error, its ratio to holding still and the context gain in translation, from
    ``lerobot-ip-action-error``'s default setting, with the two ratios' 95% intervals over tasks
    (``vs_holding_still_interval``, ``context_gain_interval``: ``[low, high]``, None for one task); for a checkpoint
    started from the replay also the replay's own ratio to holding still and own / replay with their intervals, and
    those figures for the tasks whose replay plan is right and wrong apart (``by_replay``)."""
    own, hold = result["settings"][0]["translation_mm"], result["hold"]["translation_mm"]
    shown = {"translation_mm": own, "hold_translation_mm": hold, "vs_holding_still": round(own / hold, 4),
             "context_gain": result["context_gain"]["translation"],
             "vs_holding_still_interval": result["intervals"]["vs_holding_still"],
             "context_gain_interval": result["intervals"]["context_gain_translation"]}
    if "replay" in result:
        shown.update({name: result["intervals"][name]["value"] for name in ("vs_replay", "replay_vs_holding_still")})
        shown.update({f"{name}_interval": result["intervals"][name]["ci95"]
                      for name in ("vs_replay", "replay_vs_holding_still")})
    if "by_replay" in result:  # the tasks whose replay is right and those whose replay is wrong, apart
        shown["by_replay"] = result["by_replay"]
    return shown


def per_task(result: dict) -> dict:
    """What a later run needs of ``lerobot-ip-action-error``'s ``result`` to compare itself with this one paired
    (:data:`~lerobot_instant_policy.evaluation.action_error.PAIRED_KEYS`: the seed, frames per task, horizon and the
    per-task errors)."""
    return {key: result[key] for key in PAIRED_KEYS}


def validation_record(results: dict) -> dict:
    """What a record keeps of :func:`validate`'s ``results`` (set → result): ``validation`` (set → :func:`figures`)
    and ``validation_per_task`` (set → :func:`per_task`)."""
    return {"validation": {name: figures(result) for name, result in results.items()},
            "validation_per_task": {name: per_task(result) for name, result in results.items()}}


def validation_key(config: StandingConfig) -> dict:
    """What a validation result depends on besides the checkpoint: the sets' presets (SHA-256), their size, the
    setting, the device and, where given, the replay start with the timing model its priors are read by
    (``replay_timing``: a result read with another timing is validated again)."""
    replay = {name: getattr(config, name) for name in REPLAY_OPTIONS
              if getattr(config, name) is not None}
    if config.replay_init_strength is not None:
        replay["replay_timing"] = TIMING_MODEL
    return {"presets_sha256": {name: hashlib.sha256(Path(preset).read_bytes()).hexdigest()
                               for name, preset in VALIDATION_CONFIGS.items()},
            "val_tasks": config.val_tasks, "val_frames_per_task": config.val_frames_per_task,
            "setting": {"K": EVAL_K, "N": EVAL_N, "L": EVAL_L}, "device": config.device, **replay}


def validation_env() -> dict[str, str]:
    """The environment of a validation process: one torch thread. It shares the cores with the training; measured
    on 2 cores beside two training runs, one thread predicted in 142 ms where two, spinning while they waited for
    each other, took 2.6 s."""
    return {**os.environ, "OMP_NUM_THREADS": "1"}


def validate(config: StandingConfig, checkpoint: Path, root: Path) -> dict:
    """``lerobot-ip-action-error``'s results for ``checkpoint`` (a pretrained_model folder) on both sets under
    ``root`` (set → result), cached in ``root/results/<fingerprint>.json`` with :func:`validation_key`: a checkpoint
    already validated on the same sets in the same way is read back, not run again."""
    key = {"checkpoint_sha256": checkpoint_fingerprint(checkpoint), **validation_key(config)}
    cache = root / RESULTS_DIR / f"{key['checkpoint_sha256'][:24]}.json"
    if cache.is_file():
        cached = json.loads(cache.read_text())
        if cached.get("key") == key:
            return cached["results"]
    results = {}
    for name in VALIDATION_CONFIGS:
        command = program("lerobot-ip-action-error") + [
            "--policy-path", str(checkpoint), "--root", str(root / name), "--repo-id", f"local/{name}",
            "--tasks", str(config.val_tasks), "--frames-per-task", str(config.val_frames_per_task), "--K", str(EVAL_K),
            "--N", str(EVAL_N), "--L", str(EVAL_L), "--no-untrained", "--json", "--device", config.device]
        if config.replay_init_strength is not None:
            command += ["--replay-init-strength", str(config.replay_init_strength)]
        for switch in ("replay_per_object", "replay_anchored"):
            if getattr(config, switch) is not None:
                command += [f"--{switch.replace('_', '-')}", "true" if getattr(config, switch) else "false"]
        done = subprocess.run(command, capture_output=True, text=True, env=validation_env())
        if done.returncode != 0:
            raise StandingError(f"validation on {name} failed: {done.stderr[-2000:]}")
        results[name] = json_result(done.stdout)
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({"key": key, "checkpoint": str(checkpoint), "results": results}, indent=2))
    return results


def model_dir(checkpoint: Path) -> Path:
    """The pretrained_model folder of ``checkpoint``: itself, or the one inside a save (``FileNotFoundError``
    naming it where there is none)."""
    for candidate in (checkpoint, checkpoint / MODEL_DIR):
        if (candidate / "config.json").is_file():
            return candidate
    raise FileNotFoundError(f"{checkpoint} is neither a pretrained_model folder nor a save holding one")


def compare(config: StandingConfig, checkpoints: list[Path], root: Path) -> dict:
    """Each of ``checkpoints`` (pretrained_model folders or saves) validated on both sets under ``root`` (generated
    there first where missing; results cached, :func:`validate`), its figures (:func:`figures`) and, after the
    first, its paired difference from the first (:func:`paired_against`: ``checkpoint − reference``, 95% intervals
    over tasks). A study's arms are compared so, in a process of its own while training goes on."""
    if not checkpoints:
        raise ValueError("compare needs at least one checkpoint")
    models = [model_dir(checkpoint) for checkpoint in checkpoints]
    wait_for(validation_sets(config, root), root)
    records = [validation_record(validate(config, model, root)) for model in models]
    rows = [{"checkpoint": str(model), "validation": record["validation"],
             "against_reference": paired_against(record, records[0]) if index else None}
            for index, (model, record) in enumerate(zip(models, records))]
    return {"reference": str(models[0]), "val_tasks": config.val_tasks,
            "val_frames_per_task": config.val_frames_per_task, "checkpoints": rows}


def shipped_validation(config: StandingConfig, root: Path, standing: Path = STANDING) -> dict:
    """The shipped checkpoint on both validation sets under ``root``, as a run's record holds a save's figures
    (:func:`validation_record`), with the ``key`` it was
    validated under: the SHA-256 of the checkpoint's files and of the sets' presets, the validation's size, setting
    and device. Cached in ``standing/shipped.json`` and validated again only when the key changes."""
    key = {"checkpoint_sha256": checkpoint_fingerprint(SHIPPED), **validation_key(config)}
    cache = standing / SHIPPED_RECORD
    if cache.is_file():
        cached = json.loads(cache.read_text())
        if cached.get("key") == key:
            return cached
    results = validate(config, SHIPPED, root)
    record = {"key": key, **validation_record(results)}
    standing.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps(record, indent=2))
    return record


def compare_with_shipped(config: StandingConfig, entry: dict, root: Path, standing: Path = STANDING) -> dict:
    """:func:`paired_against` the shipped checkpoint validated on the same frames (:func:`shipped_validation`); where
    that cannot be had, each set holds ``{"not_compared": why}`` (the save is kept all the same)."""
    try:
        return paired_against(entry, shipped_validation(config, root, standing))
    except (StandingError, FileNotFoundError) as error:
        return {name: {"not_compared": str(error)} for name in VALIDATION_CONFIGS}


def validate_average(config: StandingConfig, save: Path, entry: dict, root: Path, standing: Path = STANDING) -> dict:
    """The moving average a save holds (``training_state/weight_average.safetensors``) as a pretrained_model
    (``save/pretrained_model_average``), validated as the raw weights were (``entry``: the run's record so far):
    its :func:`validation_record`, ``against_raw`` (average − raw, paired) and ``against_shipped``."""
    averaged = write_averaged_model(save, save / AVERAGE_MODEL_DIR)
    record = validation_record(validate(config, averaged, root))
    return {**record, "against_raw": paired_against(record, entry),
            "against_shipped": compare_with_shipped(config, record, root, standing)}


def readout(entry: dict) -> dict:
    """What a run offers as its best: its raw weights' record, or, where its moving average validated closer to the
    actions than the raw weights on both sets (:func:`beats`), the record with the average's figures in their place
    and ``readout: "average"``."""
    average = entry.get("average")
    if average is None or not beats(average["validation"], entry["validation"]):
        return {**entry, "readout": "raw"}
    chosen = {key: value for key, value in entry.items() if key != "average"}
    return {**chosen, **{key: average[key] for key in ("validation", "validation_per_task", "against_shipped")},
            "readout": "average"}


# ---------------------------------------------------------------------------------------------------- one run
def run(config: StandingConfig, standing: Path = STANDING, curve_file: Path = CURVE_FILE) -> dict:
    """One run (module docstring); returns its record (what the save's ``standing.json`` holds, last run last)."""
    config.validate()
    started = time.monotonic()
    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    work = Path(config.work)
    train_dir = work / f"run-{datetime.now(timezone.utc):%Y%m%dT%H%M%S}"
    start = start_save(config, standing)
    resume_from = (_stage_resume(start, train_dir, config.base_lr, config.weight_decay)
                   if start is not None else None)
    log_path = train_dir.with_suffix(".log")
    log_path.parent.mkdir(parents=True, exist_ok=True)  # a fresh start's train_dir is LeRobot's to create
    env = {**os.environ, "OMP_NUM_THREADS": str(config.train_threads), "HF_HUB_OFFLINE": "1"}
    with open(log_path, "w") as log:
        training = subprocess.Popen(train_command(config, resume_from, train_dir), stdout=log,
                                    stderr=subprocess.STDOUT, env=env, start_new_session=True,
                                    preexec_fn=lambda: os.nice(config.nice))
    generating = validation_sets(config, work / "validation")
    stop_at = started + config.deadline_s - config.validate_s
    while time.monotonic() < stop_at and training.poll() is None:
        time.sleep(5.0)
    if training.poll() is None:
        os.killpg(training.pid, signal.SIGTERM)
        training.wait(timeout=120)
    return conclude(config, train_dir, start, started_at, started, standing, curve_file, generating)


def conclude(config: StandingConfig, train_dir: Path, start: Path | None, started_at: str, started: float,
             standing: Path = STANDING, curve_file: Path = CURVE_FILE,
             generating: dict[str, subprocess.Popen | None] | None = None) -> dict:
    """What a run does once its training has stopped: validate the last complete save under ``train_dir`` (not the
    resumed ``start`` staged there) on the sets under ``config.work``'s ``validation/`` (``generating``: their
    generation still under way), record it after ``start``'s record (``started_at``, and ``started``: the
    ``time.monotonic()`` of the start, for its wall time) and keep or pack it. ``python -m workbench.cli.standing
    conclude TRAIN_DIR`` runs it for a run whose process stopped before it did. Returns the record."""
    work = Path(config.work)
    previous = read_record(start) if start is not None else {"runs": []}
    start_step = step_of(start) if start is not None else 0
    resume_from = staged_start(train_dir, start_step) if start is not None else None
    log_path = train_dir.with_suffix(".log")
    saves = [save for save in complete_saves(train_dir) if save != resume_from]
    if not saves:
        raise StandingError(f"no save completed before the deadline; training log:\n{log_path.read_text()[-3000:]}")
    save = saves[-1]
    validation = work / "validation"
    wait_for(generating if generating is not None else validation_sets(config, validation), validation)
    results = validate(config, save / MODEL_DIR, validation)
    pool = json.loads((save / POOL_STATE).read_text())["stats"]
    steps = step_of(save) - start_step
    samples, tasks = steps * config.batch_size, pool["distinct_tasks_used"]
    before = previous["runs"][-1] if previous["runs"] else {"samples_total": config.prior_samples,
                                                            "tasks_total": config.prior_tasks}
    entry = {
        "started": started_at, "device": config.device, "start": str(start) if start else str(SHIPPED),
        "start_step": start_step, "end_step": step_of(save), "samples": samples, "tasks": tasks,
        "samples_total": before["samples_total"] + samples, "tasks_total": before["tasks_total"] + tasks,
        "trained_s": round(pool["elapsed_s"], 1), "wall_s": round(time.monotonic() - started, 1),
        "pool": pool, **validation_record(results), "config": asdict(config),
        "hidden_dim": json.loads((save / MODEL_DIR / "config.json").read_text())["hidden_dim"],
    }
    entry["against_shipped"] = compare_with_shipped(config, entry, work / "validation", standing)
    if (save / STATE_DIR / AVERAGE_FILE).is_file():
        entry["average"] = validate_average(config, save, entry, work / "validation", standing)
    record = {"runs": [*previous["runs"], entry]}
    (save / RECORD).write_text(json.dumps(record, indent=2))
    if config.out:
        pack(save, Path(config.out))
    else:
        keep(save, standing, curve_file)
        record = read_record(standing / "last")
    return record


def conclude_stopped(config: StandingConfig, train_dir: Path, standing: Path = STANDING,
                     curve_file: Path = CURVE_FILE) -> dict:
    """:func:`conclude` for a run whose process stopped before it did (killed, or its session ended): the start is
    the save it resumed (the standing run's last, as :func:`start_save` finds it before the run is kept), the start
    time the one its folder is named after (``run-YYYYmmddTHHMMSS``, UTC)."""
    config.validate()
    started = datetime.strptime(train_dir.name, "run-%Y%m%dT%H%M%S").replace(tzinfo=timezone.utc)
    elapsed = (datetime.now(timezone.utc) - started).total_seconds()
    return conclude(config, train_dir, start_save(config, standing), started.isoformat(timespec="seconds"),
                    time.monotonic() - elapsed, standing, curve_file)


# ---------------------------------------------------------------------------------------------------- keeping
def beats(validation: dict, best: dict | None) -> bool:
    """Whether ``validation`` is closer than ``best`` (a kept run's figures; None: nothing kept yet) to the actions
    on both sets, relative to holding still."""
    return best is None or all(validation[name]["vs_holding_still"] < best[name]["vs_holding_still"]
                               for name in VALIDATION_CONFIGS)


def paired_against(entry: dict, other: dict) -> dict:
    """The paired difference, ``entry`` − ``other``, of the error over holding still's and of the context gain on each
    validation set (:func:`~lerobot_instant_policy.evaluation.action_error.paired_ratio_difference` of their
    ``validation_per_task``; in each ratio ``a`` is ``entry``'s, ``b`` ``other``'s). A set where the two cannot be
    paired (a record older than its per-task errors, other frames) holds ``{"not_compared": why}``."""
    comparison = {}
    for name in VALIDATION_CONFIGS:
        try:
            comparison[name] = paired_ratio_difference(entry.get("validation_per_task", {}).get(name, {}),
                                                       other.get("validation_per_task", {}).get(name, {}))
        except ActionErrorError as error:
            comparison[name] = {"not_compared": str(error)}
    return comparison


def against_best(entry: dict, best: dict) -> dict:
    """:func:`paired_against` the best (``entry``, ``best``: runs of a record), with the best's end step and
    samples."""
    return {"best_end_step": best["end_step"], "best_samples_total": best["samples_total"],
            **paired_against(entry, best)}


def beats_shipped(entry: dict | None) -> bool | None:
    """Whether a run's save is closer than the shipped checkpoint to the actions on both sets, relative to holding
    still (the point estimates of its ``against_shipped``, the rule :func:`beats` applies to the best); None where a
    set was not compared."""
    comparison = (entry or {}).get("against_shipped", {})
    differences = [comparison.get(name, {}).get("vs_holding_still", {}).get("difference")
                   for name in VALIDATION_CONFIGS]
    return None if None in differences else all(difference < 0 for difference in differences)


def keep(save: Path, standing: Path = STANDING, curve_file: Path = CURVE_FILE) -> dict:
    """Make ``save`` (a folder with ``pretrained_model/``, ``training_state/`` and ``standing.json``) the run's last
    save, its weights the best when they beat the best on both sets, and add its point to the curve. Where a best is
    kept already, the run's record in the last save (and in the best, when it becomes the best) also holds
    ``against_best`` (:func:`against_best`: the paired difference from the previous best, whatever the rule
    decides), and ``best_beats_shipped`` (:func:`beats_shipped` of the best after this run: step 5 is due when
    true). Returns ``best`` (kept as the best), the curve's ``point``, ``against_best`` (None without a best) and
    ``best_beats_shipped``."""
    record = read_record(save)
    entry = record["runs"][-1]
    last, best = standing / "last", standing / "best"
    previous_best = read_record(best)["runs"][-1] if (best / RECORD).is_file() else None
    candidate = readout(entry)
    if previous_best is not None:
        entry["against_best"] = candidate["against_best"] = against_best(candidate, previous_best)
    kept = beats(candidate["validation"], previous_best["validation"] if previous_best is not None else None)
    entry["best_beats_shipped"] = candidate["best_beats_shipped"] = beats_shipped(candidate if kept else previous_best)
    staging = standing / ".last-new"
    shutil.rmtree(staging, ignore_errors=True)
    write_compact(save, staging)
    (staging / RECORD).write_text(json.dumps(record, indent=2))
    shutil.rmtree(last, ignore_errors=True)
    staging.rename(last)  # the old last save stays whole until the new one is complete
    if kept:
        shutil.rmtree(best, ignore_errors=True)
        best.mkdir(parents=True)
        # the compact last save holds the average where the save keeps one, else the raw weights: a best of the
        # same weights is copied from it, the same file's bytes (one blob in git, not two)
        same_as_last = candidate["readout"] == "average" or not (save / STATE_DIR / AVERAGE_FILE).is_file()
        shutil.copytree((last if same_as_last else save) / MODEL_DIR, best / MODEL_DIR)
        (best / RECORD).write_text(json.dumps({"runs": [candidate]}, indent=2))
    point = curve_point(entry["samples_total"], entry["tasks_total"], entry["hidden_dim"], entry["device"],
                        entry["validation"], entry["config"]["val_tasks"], entry["config"]["val_frames_per_task"],
                        kept, f"standing run from step {entry['start_step']} to {entry['end_step']}, "
                              f"{entry['started']}, {entry['device']}")
    add_curve_point(point, curve_file)
    return {"best": kept, "point": point, "against_best": entry.get("against_best"),
            "best_beats_shipped": entry["best_beats_shipped"]}


def write_compact(save: Path, out: Path) -> None:
    """What resuming ``save`` (a LeRobot step checkpoint) needs, written to ``out`` as it is committed:
    ``pretrained_model/`` holding the moving average's weights where the save keeps one (the raw weights where it
    does not), so a resumed run goes on from the average and its new average starts there; ``training_state/``
    without the optimizer's moments and the average (:data:`COMPACT_OMITS`: 24 of the save's 32 MB), which a resumed
    optimizer rebuilds (``moment_rebuild_steps``). One weights file a save, not three."""
    if (save / STATE_DIR / AVERAGE_FILE).is_file():
        write_averaged_model(save, out / MODEL_DIR)
    else:
        shutil.copytree(save / MODEL_DIR, out / MODEL_DIR)
    shutil.copytree(save / STATE_DIR, out / STATE_DIR, ignore=shutil.ignore_patterns(*COMPACT_OMITS))


def pack(save: Path, out: Path) -> None:
    """``save`` (with its ``standing.json``) as a device brings it back for :func:`accept`: ``save.tar`` and the
    record beside it in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    with tarfile.open(out / SAVE_TAR, "w") as archive:
        for part in (MODEL_DIR, STATE_DIR, RECORD):
            archive.add(save / part, arcname=part)
    shutil.copyfile(save / RECORD, out / RECORD)


def accept(folder: Path, standing: Path = STANDING, curve_file: Path = CURVE_FILE) -> dict:
    """Keep a run brought back from a device (``save.tar`` and ``standing.json`` in ``folder``). Where the device did
    not compare the save with the shipped checkpoint (a device call carries 64 MiB, and the tree may travel without
    it), the comparison is made here, the shipped checkpoint validated on this machine's CPU on the run's validation
    sets (generated under the run's ``work`` where missing) and cached as a local run's is."""
    unpacked = folder / "unpacked"
    shutil.rmtree(unpacked, ignore_errors=True)
    with tarfile.open(folder / SAVE_TAR) as archive:
        archive.extractall(unpacked, filter="data")
    record = read_record(unpacked)
    entry = record["runs"][-1]
    if beats_shipped(entry) is None:
        config = StandingConfig(**{**entry["config"], "device": "cpu", "out": None})
        root = Path(config.work) / "validation"
        wait_for(validation_sets(config, root), root)
        entry["against_shipped"] = compare_with_shipped(config, entry, root, standing)
        (unpacked / RECORD).write_text(json.dumps(record, indent=2))
    return keep(unpacked, standing, curve_file)


# ---------------------------------------------------------------------------------------------------- the curve
def curve_point(samples_total: int, tasks_total: int, hidden_dim: int, device: str, validation: dict,
                val_tasks: int, val_frames_per_task: int, kept: bool, source: str) -> dict:
    """One point of the scaling curve: what was seen (samples and distinct tasks, every lease so far), the width and
    where it trained, and the checkpoint's figures on each validation set (``validation``: set → :func:`figures`,
    as ``<set>_<figure>``; runs validated before the intervals were kept have no ``*_interval``)."""
    return {"samples_total": samples_total, "tasks_total": tasks_total, "hidden_dim": hidden_dim, "device": device,
            "kept": kept, "val_tasks": val_tasks, "val_frames_per_task": val_frames_per_task, "source": source,
            **{f"{name}_{key}": value for name, result in validation.items() for key, value in result.items()}}


def add_curve_point(point: dict, curve_file: Path = CURVE_FILE) -> None:
    """Append ``point`` to the curve's JSON and redraw its picture beside it (``.png``)."""
    curve = json.loads(curve_file.read_text()) if curve_file.is_file() else {"points": []}
    curve["points"].append(point)
    curve_file.write_text(json.dumps(curve, indent=2))
    plot_curve(curve["points"], curve_file.with_suffix(".png"))


def plot_curve(points: list[dict], png: Path) -> None:
    """Error against holding still and context gain on both validation sets, against samples seen (log axis), one
    marker per device and width (CPU points hollow), with an error bar (the 95% interval over tasks) on each point
    that has one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(10, 4))
    for axis, key, label in ((axes[0], "vs_holding_still", "error / holding still (lower is better)"),
                             (axes[1], "context_gain", "context gain, swap / own error (higher is better)")):
        for name, color in (("moved", "tab:red"), ("one_layout", "tab:blue")):
            for (device, width), group in _groups(points).items():
                chosen = sorted(group, key=lambda point: point["samples_total"])
                xs = [max(point["samples_total"], 1) for point in chosen]
                ys = [point[f"{name}_{key}"] for point in chosen]
                axis.plot(xs, ys, "-o", color=color, markerfacecolor="none" if device == "cpu" else color,
                          label=f"{name.replace('_', ' ')}, {device}, hidden {width}")
                bars = [(x, y, point[f"{name}_{key}_interval"]) for x, y, point in zip(xs, ys, chosen)
                        if point.get(f"{name}_{key}_interval") is not None]
                if bars:
                    axis.errorbar([x for x, _, _ in bars], [y for _, y, _ in bars], fmt="none", ecolor=color,
                                  capsize=3, yerr=[[max(y - low, 0.0) for _, y, (low, _) in bars],
                                                   [max(high - y, 0.0) for _, y, (_, high) in bars]])
        axis.set_xscale("log")
        axis.set_xlabel("samples seen on the stream (log; 0 drawn at 1)")
        axis.set_ylabel(label)
        axis.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    figure.suptitle("instant_policy on the pseudo-task stream: held-out pseudo-tasks, held-out objects\n"
                    "bars: 95% intervals over tasks, where measured", fontsize=10)
    figure.tight_layout()
    figure.savefig(png, dpi=120)
    plt.close(figure)


def _groups(points: list[dict]) -> dict[tuple[str, int], list[dict]]:
    groups: dict[tuple[str, int], list[dict]] = {}
    for point in points:
        groups.setdefault((point["device"], point["hidden_dim"]), []).append(point)
    return groups


TREND_FIGURES = {"vs_holding_still": 0.5, "context_gain": 2.0}  # the aim on fresh moved-object tasks


def trend(points: list[dict], min_samples: int = 1, targets: dict[str, float] = TREND_FIGURES) -> dict:
    """What the curve predicts: for each set and figure (``<set>_<figure>``, ``targets``: figure → the value aimed
    at), the least-squares line y = a + b·log10(samples) through the points with at least ``min_samples``, its slope
    per tenfold samples with a 95% interval (Student's t over n − 2 degrees of freedom), and the samples at which the
    line reaches the target: ``samples_at_target`` from the fitted slope (None where it does not lead towards the
    target: no crossing is predicted) and ``samples_at_target_interval`` ``[nearest, farthest]`` from the slope's
    bounds through the points' centroid (``farthest`` None, unbounded, where the slope's interval reaches a flat or
    wrong-way slope; both None where the whole interval does). ``ValueError`` with fewer than three points."""
    import numpy as np
    from scipy import stats

    chosen = sorted((point for point in points if point["samples_total"] >= min_samples),
                    key=lambda point: point["samples_total"])
    if len(chosen) < 3:
        raise ValueError(f"a trend needs at least 3 points with ≥ {min_samples} samples, the curve has {len(chosen)}")
    x = np.log10([point["samples_total"] for point in chosen])
    result = {"points": len(chosen), "samples": [chosen[0]["samples_total"], chosen[-1]["samples_total"]]}
    for name in VALIDATION_CONFIGS:
        for figure, target in targets.items():
            y = np.array([point[f"{name}_{figure}"] for point in chosen])
            fit = stats.linregress(x, y)
            half = stats.t.ppf(0.975, len(chosen) - 2) * fit.stderr
            slopes = (fit.slope - half, fit.slope + half)

            def crossing(slope: float) -> float | None:
                towards = (target - y.mean()) * slope > 0
                return round(float(10 ** (x.mean() + (target - y.mean()) / slope))) if towards else None

            crossings = sorted(value for value in map(crossing, slopes) if value is not None)
            result[f"{name}_{figure}"] = {
                "target": target, "slope_per_decade": round(float(fit.slope), 4),
                "slope_interval": [round(float(slope), 4) for slope in slopes],
                "at_last_point": round(float(fit.intercept + fit.slope * x[-1]), 4),
                "samples_at_target": crossing(fit.slope),
                "samples_at_target_interval": [crossings[0] if crossings else None,
                                               crossings[1] if len(crossings) == 2 else None]}
    return result
