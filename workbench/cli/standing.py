"""``python -m workbench.cli.standing`` (from the repository root): the command line of :mod:`workbench.standing`.

  run --hours 2.5                                   (here: continue checkpoints/stream/last on the CPU pool, nice)
  run --device cuda --generator-device cpu --generators 13 --batch-size 64 --out DIR   (a GPU lease: gpu_standing.sh)
  accept FOLDER                                     (here: keep what a lease brought back)
  conclude outputs/standing/run-<UTC start> [--hours 2.5 ...]   (a run whose process stopped before it kept its save)
  compare REFERENCE SAVE [SAVE ...]                 (a study's arms, paired on the validation sets, results cached)
  average SAVE [SAVE ...] --out DIR                 (the mean of saves' weights, a pretrained_model to compare)
  trend --min-samples 140000                        (what the curve predicts, from its points since a recipe began)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..standing import (
    CURVE_FILE,
    PROG,
    REPLAY_OPTIONS,
    STANDING,
    StandingConfig,
    StandingError,
    accept,
    compare,
    conclude_stopped,
    model_dir,
    run,
    trend,
)
from ..tail_average import write_average


def add_run_options(command: argparse.ArgumentParser, defaults: StandingConfig) -> None:
    """The options of a run (:class:`StandingConfig`'s fields): ``run`` trains with them, ``conclude`` records
    them as the run's."""
    command.add_argument("--hours", type=float, help="the deadline in hours (instead of --deadline-s)")
    for name in ("work", "out", "start", "stream_config", "device", "generator_device"):
        command.add_argument(f"--{name.replace('_', '-')}", default=getattr(defaults, name))
    for name in ("deadline_s", "validate_s", "optimizer_lr", "base_lr", "weight_decay", "average_decay"):
        command.add_argument(f"--{name.replace('_', '-')}", type=float, default=getattr(defaults, name))
    for name in ("seed", "batch_size", "samples_per_task", "tasks_per_render", "surface_samples", "capacity",
                 "min_tasks", "generators",
                 "generator_threads", "train_threads", "save_freq", "log_freq", "nice", "val_tasks",
                 "val_frames_per_task", "val_workers", "prior_samples", "prior_tasks", "moment_rebuild_steps"):
        command.add_argument(f"--{name.replace('_', '-')}", type=int, default=getattr(defaults, name))
    command.add_argument("--lerobot-arg", dest="lerobot_args", action="append", default=[], metavar="FLAG",
                         help="a further lerobot-train flag, e.g. --lerobot-arg=--policy.optimizer_lr=3e-4")
    add_replay_options(command)


def add_replay_options(command: argparse.ArgumentParser) -> None:
    """The validation's replay start (:class:`StandingConfig`'s ``replay_*`` fields; unset: the checkpoint's)."""
    command.add_argument("--replay-init-strength", type=float,
                         help="validate every checkpoint started from the replay, noised to this strength")
    for name, plan in (("replay_per_object", "per object"), ("replay_anchored", "per segment, anchored")):
        command.add_argument(f"--{name.replace('_', '-')}", choices=["true", "false"],
                             help=f"that replay planned {plan}")


def replay_options(args: argparse.Namespace) -> dict:
    """:func:`add_replay_options`' values as :class:`StandingConfig`'s fields."""
    switches = {name: None if getattr(args, name) is None else getattr(args, name) == "true"
                for name in ("replay_per_object", "replay_anchored")}
    return {"replay_init_strength": args.replay_init_strength, **switches}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("--standing", type=Path, default=STANDING, help="where the last and best saves live")
    parser.add_argument("--curve", type=Path, default=CURVE_FILE, help="the scaling curve's JSON (its picture beside)")
    commands = parser.add_subparsers(dest="command", required=True)
    defaults = StandingConfig()
    one = commands.add_parser("run", help="continue the standing run to a deadline, validate, keep")
    ended = commands.add_parser("conclude", help="validate, record and keep a run whose process stopped before it did")
    ended.add_argument("train_dir", type=Path, help="the run's folder, outputs/standing/run-<UTC start>")
    for command in (one, ended):
        add_run_options(command, defaults)
    brought = commands.add_parser("accept", help="keep a run brought back from a device (save.tar, standing.json)")
    brought.add_argument("folder", type=Path)
    paired = commands.add_parser("compare", help="validate checkpoints on both sets, each paired against the first")
    paired.add_argument("checkpoints", type=Path, nargs="+", help="pretrained_model folders or saves holding one")
    paired.add_argument("--work", default=defaults.work, help="its validation/ holds the sets and cached results")
    paired.add_argument("--device", default=defaults.device)
    for name in ("val_tasks", "val_frames_per_task", "val_workers"):
        paired.add_argument(f"--{name.replace('_', '-')}", type=int, default=getattr(defaults, name))
    add_replay_options(paired)
    mean = commands.add_parser("average", help="write the mean of saves' weights as a pretrained_model")
    mean.add_argument("checkpoints", type=Path, nargs="+", help="pretrained_model folders or saves holding one")
    mean.add_argument("--out", type=Path, required=True, help="a new folder for the averaged pretrained_model")
    predicted = commands.add_parser("trend", help="fit each figure against log samples, say where it meets the aim")
    predicted.add_argument("--min-samples", type=int, default=1,
                           help="fit only the points with at least these samples (one recipe's points)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "accept":
            result = accept(args.folder, args.standing, args.curve)
        elif args.command == "compare":
            config = StandingConfig(work=args.work, device=args.device, val_tasks=args.val_tasks,
                                    val_frames_per_task=args.val_frames_per_task, val_workers=args.val_workers,
                                    **replay_options(args))
            config.validate()
            result = compare(config, args.checkpoints, Path(args.work) / "validation")
        elif args.command == "average":
            models = [model_dir(checkpoint) for checkpoint in args.checkpoints]
            result = {"out": str(write_average(models, args.out)), "averaged": [str(model) for model in models]}
        elif args.command == "trend":
            result = trend(json.loads(args.curve.read_text())["points"], args.min_samples)
        else:
            options = {key: value for key, value in vars(args).items()
                       if key not in ("command", "hours", "standing", "curve", "train_dir", *REPLAY_OPTIONS)}
            options.update(replay_options(args))
            if args.hours is not None:
                options["deadline_s"] = args.hours * 3600
            config = StandingConfig(**options)
            if args.command == "conclude":
                result = conclude_stopped(config, args.train_dir, args.standing, args.curve)["runs"][-1]
            else:
                result = run(config, args.standing, args.curve)["runs"][-1]
    except (StandingError, ValueError, FileNotFoundError, FileExistsError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    if result.get("best_beats_shipped"):
        print(f"{PROG}: the best save beats the shipped checkpoint on both sets: step 5 is due "
              "(make results-candidate, docs/training.md)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
