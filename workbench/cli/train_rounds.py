"""``python -m workbench.cli.train_rounds`` (from the repository root): the command line of
:mod:`workbench.train_rounds` (train on pseudo-demonstrations generated while training runs, in rounds; ``make
train-gpu``, ``make campaign``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys

from lerobot_instant_policy.config_io import load_config
from lerobot_instant_policy.pseudo_demos.tasks import FAMILIES

from ..train_rounds import PROG, Layout, TrainRoundsConfig, TrainRoundsError, dry_run, run


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Train instant_policy in rounds: each round's pseudo-tasks are generated while the previous "
        "round trains, appended to the training dataset, and lerobot-train resumes on the grown data; then the "
        "action error, context gain and loss curve. Rerun the same command to resume. Extra --policy.* arguments "
        "go to the first lerobot-train call.",
    )
    parser.add_argument("--config", help="JSON file of TrainRoundsConfig keys (e.g. configs/train_rounds/gpu.json)")
    parser.add_argument("--out", help="output directory (state, datasets, run, logs, results)")
    parser.add_argument("--family", choices=list(FAMILIES), help="pseudo-task family (rung of the ladder)")
    parser.add_argument("--tasks-per-round", type=int, help="pseudo-tasks generated per round")
    parser.add_argument("--demos-per-task", type=int, help="demonstrations per pseudo-task")
    parser.add_argument("--rounds", type=int, help="rounds R (may be raised to continue a finished run)")
    parser.add_argument("--steps-per-round", type=int, help="optimiser steps per round")
    parser.add_argument("--batch-size", type=int, help="training batch size (per GPU)")
    parser.add_argument("--workers", type=int, help="generation processes")
    parser.add_argument("--num-workers", type=int, help="lerobot-train data-loader processes")
    parser.add_argument("--device", help="torch device of training and evaluation (cuda, cpu)")
    parser.add_argument("--start", help="fresh | shipped | a pretrained_model directory to start from")
    parser.add_argument("--seed", type=int, help="seed of round 0 (round k: seed + k) and of lerobot-train")
    parser.add_argument("--val-tasks", type=int, help="held-out validation pseudo-tasks")
    parser.add_argument("--val-demos-per-task", type=int, help="demonstrations per validation task (at least 3)")
    parser.add_argument("--shared-layout-fractions", type=float, nargs="+", metavar="P",
                        help="fraction of one-layout tasks per round (the last repeats): e.g. 0.5 0.25 0.1 0 anneals "
                             "from the live layout to objects that move between demonstrations")
    parser.add_argument("--layout-shifts", type=float, nargs="+", metavar="F",
                        help="how far the moved-object tasks move their objects per round (the last repeats): e.g. "
                             "0.25 0.5 1 grows the moves from near the live layout to independent draws")
    parser.add_argument("--launcher", help="command before lerobot-train, e.g. 'accelerate launch --multi_gpu "
                        "--num_processes=4'")
    parser.add_argument("--dry-run", action="store_true", help="print the stages and commands, run nothing")
    return parser


def config_from_args(args: argparse.Namespace, policy_overrides: list[str]) -> TrainRoundsConfig:
    try:
        config = load_config(TrainRoundsConfig, args.config) if args.config else TrainRoundsConfig()
    except ValueError as error:
        raise TrainRoundsError(str(error)) from error
    overrides = {name: getattr(args, name) for name in (
        "out", "family", "tasks_per_round", "demos_per_task", "rounds", "steps_per_round", "batch_size", "workers",
        "num_workers", "device", "start", "seed", "val_tasks", "val_demos_per_task", "shared_layout_fractions",
        "layout_shifts")}
    if args.launcher is not None:
        overrides["launcher"] = shlex.split(args.launcher)
    config = dataclasses.replace(config, **{key: value for key, value in overrides.items() if value is not None})
    config.policy_overrides = config.policy_overrides + policy_overrides
    config.validate()
    return config


def main(argv: list[str] | None = None) -> int:
    args, unknown = build_parser().parse_known_args(argv)
    not_policy = [arg for arg in unknown if not arg.startswith("--policy.")]
    if not_policy:
        print(f"{PROG}: error: unrecognized arguments: {' '.join(not_policy)}", file=sys.stderr)
        return 2
    try:
        config = config_from_args(args, unknown)
        if args.dry_run:
            dry_run(config, Layout(config.out))
            return 0
        result = run(config)
    except (TrainRoundsError, FileNotFoundError, FileExistsError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
