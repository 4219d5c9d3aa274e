"""``python -m workbench.cli.stream_lease`` (from the repository root): the command line of
:mod:`workbench.stream_lease`.

  run --out $OUT --deadline-s 540                 (on the device: train to the deadline, validate, weights to $OUT)
  run --out outputs/lease_cpu --device cpu --deadline-s 420 --batch-size 2 --samples-per-task 4 --save-freq 2 \\
      --val-tasks 2 --val-frames-per-task 2       (the same lease end to end on a CPU)
  accept FOLDER [--name NAME]                     (here: the point on the scaling curve; the weights kept if better)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..stream_lease import PROG, LeaseConfig, LeaseError, accept, run


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    lease = commands.add_parser("run", help="one lease: train on the stream to a deadline, validate, bring back")
    defaults = LeaseConfig()
    for name in ("out", "stream_config", "start", "device"):
        lease.add_argument(f"--{name.replace('_', '-')}", default=getattr(defaults, name))
    for name in ("deadline_s", "validate_s"):
        lease.add_argument(f"--{name.replace('_', '-')}", type=float, default=getattr(defaults, name))
    for name in ("batch_size", "samples_per_task", "num_workers", "save_freq", "log_freq", "val_tasks",
                 "val_frames_per_task", "generate_workers", "seed_base"):
        lease.add_argument(f"--{name.replace('_', '-')}", type=int, default=getattr(defaults, name))
    lease.add_argument("--lerobot-arg", dest="lerobot_args", action="append", default=[], metavar="FLAG",
                       help="a further lerobot-train flag, e.g. --lerobot-arg=--policy.optimizer_lr=3e-4")
    kept = commands.add_parser("accept", help="add a brought-back lease to the curve; keep its weights if better")
    kept.add_argument("folder", type=Path)
    kept.add_argument("--name", help="its folder under checkpoints/stream (default lease_NNN)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "accept":
            result = accept(args.folder, args.name)
        else:
            options = {key: value for key, value in vars(args).items() if key != "command"}
            result = run(LeaseConfig(**options))
            result.pop("log_tail")
    except (LeaseError, ValueError, FileNotFoundError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
