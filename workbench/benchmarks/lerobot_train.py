"""Speed of ``lerobot-train`` itself on a dataset: the data loader, LeRobot's loop and the policy's update together
(``python -m workbench.cli.bench lerobot-train``).

``lerobot-ip-bench train-step`` times one update in isolation. This runs the real command, ``python -m
lerobot.scripts.lerobot_train`` with the shipped model, for ``steps`` steps per variant, reads every log line
LeRobot prints (``updt_s``, ``data_s``, ``smp/s``, averages over ``log_freq`` steps) and stamps it on arrival. Lines
after ``skip`` steps count (compiling and warm-up come before): ``samples_per_s_wall`` is the batch size times the
steps between the first and the last counted line over the seconds between their arrivals, end to end (checkpointing
is off, so nothing else runs); ``updt_s`` and ``data_s`` are the medians of the counted lines. A variant is a number
of loader workers (``--num_workers``) and an OpenMP wait policy for the torch threads (``OMP_WAIT_POLICY``: ``default``
leaves it unset); the variants run in alternation ``rounds`` times, and the first variant's medians divide the others'.
"""

from __future__ import annotations

import itertools
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

#: LeRobot's training command as a module (``lerobot-train``'s entry point), run with this Python.
LEROBOT_TRAIN_MODULE = "lerobot.scripts.lerobot_train"
#: One of LeRobot's training log lines (``lerobot_train.py``): the step, then the averages of its log window.
LOG_LINE = re.compile(r"step:(?P<step>[0-9.]+[KMBT]?) .*updt_s:(?P<updt_s>[0-9.]+) data_s:(?P<data_s>[0-9.]+)")
OMP_WAIT_POLICIES = ("default", "active", "passive")
_SUFFIX = {"": 1, "K": 1_000, "M": 1_000_000, "B": 1_000_000_000, "T": 1_000_000_000_000}


@dataclass(frozen=True)
class LogLine:
    """A training log line: ``step`` (LeRobot rounds it to 3 digits from 1K), window averages, arrival time (s)."""

    step: int
    updt_s: float
    data_s: float
    arrival_s: float


def parse_log_line(line: str, arrival_s: float) -> LogLine | None:
    """The :class:`LogLine` in one line of ``lerobot-train``'s output, or None if it is not a training log line."""
    match = LOG_LINE.search(line)
    if match is None:
        return None
    number, suffix = re.fullmatch(r"([0-9.]+)([KMBT]?)", match["step"]).groups()
    return LogLine(round(float(number) * _SUFFIX[suffix]), float(match["updt_s"]), float(match["data_s"]), arrival_s)


def summarize(lines: list[LogLine], batch_size: int, skip: int) -> dict:
    """Figures of one run from its log lines: those after ``skip`` steps count; at least two are needed."""
    counted = [line for line in lines if line.step > skip]
    if len(counted) < 2:
        raise ValueError(f"{len(counted)} log lines after step {skip}: raise --steps or lower --skip/--log-every")
    first, last = counted[0], counted[-1]
    return {
        "samples_per_s_wall": round(batch_size * (last.step - first.step) / (last.arrival_s - first.arrival_s), 1),
        "updt_s": statistics.median(line.updt_s for line in counted),
        "data_s": statistics.median(line.data_s for line in counted),
        "log_lines": len(counted),
    }


def lerobot_train_command(root: str, repo_id: str, output_dir: str, steps: int, batch_size: int, num_workers: int,
                          log_every: int, compile_model: bool) -> list[str]:
    """``lerobot-train`` of the default model and recipe (the shipped model's, ``InstantPolicyConfig``'s defaults) in
    bfloat16 autocast, no checkpoints, no W&B."""
    return [
        sys.executable, "-m", LEROBOT_TRAIN_MODULE, "--policy.type=instant_policy", "--policy.use_amp=true",
        f"--policy.compile_model={str(compile_model).lower()}", "--policy.push_to_hub=false",
        f"--dataset.repo_id={repo_id}", f"--dataset.root={root}",
        f"--steps={steps}", f"--batch_size={batch_size}", f"--num_workers={num_workers}", f"--log_freq={log_every}",
        f"--save_freq={steps + 1}", "--save_checkpoint=false", "--seed=1", "--wandb.enable=false",
        f"--output_dir={output_dir}",
    ]


def run_lerobot_train(command: list[str], env: dict[str, str]) -> list[LogLine]:
    """Run ``command``, stamping its log lines on arrival; a failed run raises with the end of its output."""
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    lines, tail = [], deque(maxlen=20)
    for raw in process.stdout:  # tqdm's carriage returns stay inside a line; LeRobot's log ends it
        text = raw.decode(errors="replace")
        tail.append(text)
        line = parse_log_line(text, time.perf_counter())
        if line is not None:
            lines.append(line)
    if process.wait() != 0:
        raise RuntimeError(f"lerobot-train exited with {process.returncode}:\n" + "".join(tail)[-4000:])
    return lines


def bench_lerobot_train(root: str, repo_id: str | None = None, steps: int = 500, skip: int = 200,
                        batch_size: int = 8, log_every: int = 50, threads: int = 2, num_workers: tuple[int, ...] = (1,),
                        omp_wait_policies: tuple[str, ...] = ("default",), compile_model: bool = False,
                        rounds: int = 1) -> dict:
    """Every (loader workers, OpenMP wait policy) variant in alternation ``rounds`` times; medians over rounds."""
    if not (Path(root) / "meta" / "info.json").is_file():
        raise FileNotFoundError(f"{root} is not a LeRobotDataset (no meta/info.json)")
    unknown = sorted(set(omp_wait_policies) - set(OMP_WAIT_POLICIES))
    if unknown:
        raise ValueError(f"unknown OpenMP wait policies {unknown}: choose from {list(OMP_WAIT_POLICIES)}")
    if skip >= steps:
        raise ValueError(f"--skip ({skip}) must be below --steps ({steps})")
    repo_id = repo_id or f"local/{Path(root).name}"
    variants = list(itertools.product(num_workers, omp_wait_policies))
    runs = {variant: [] for variant in variants}
    for _ in range(rounds):
        for workers, policy in variants:
            env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
            env.pop("OMP_WAIT_POLICY", None)
            if policy != "default":
                env["OMP_WAIT_POLICY"] = policy.upper()
            output_dir = tempfile.mkdtemp(prefix="ip-bench-train-")
            shutil.rmtree(output_dir)  # lerobot-train refuses an existing output directory without --resume
            try:
                command = lerobot_train_command(root, repo_id, output_dir, steps, batch_size, workers, log_every,
                                                compile_model)
                runs[(workers, policy)].append(summarize(run_lerobot_train(command, env), batch_size, skip))
            finally:
                shutil.rmtree(output_dir, ignore_errors=True)
    results = []
    for (workers, policy), figures in runs.items():
        results.append({
            "num_workers": workers, "omp_wait_policy": policy,
            **{key: statistics.median(run[key] for run in figures) for key in ("samples_per_s_wall", "updt_s", "data_s")},
            "runs_samples_per_s_wall": [run["samples_per_s_wall"] for run in figures],
        })
    for result in results[1:]:
        result["over_first"] = round(result["samples_per_s_wall"] / results[0]["samples_per_s_wall"], 3)
    return {
        "benchmark": "lerobot-train", "root": root, "batch": batch_size, "steps": steps, "skip": skip,
        "log_every": log_every, "torch_threads": threads, "compile_model": compile_model, "rounds": rounds,
        "variants": results,
    }
