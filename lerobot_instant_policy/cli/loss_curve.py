"""``lerobot-ip-loss-curve``: the training curve of an ``instant_policy`` run as a PNG (and a JSON of the figures).

Every ``OUTPUT_DIR/checkpoints/<step>/pretrained_model`` of a ``lerobot-train`` run is evaluated on a fixed, seeded
sample of frames of the training dataset (training loss) and of a held-out pseudo-task dataset (validation loss), and on
the held-out frames with every frame's demonstrations swapped for another pseudo-task's (the context swap); the
held-out translation and rotation losses are drawn against the prior-only level. See
:mod:`lerobot_instant_policy.evaluation.loss_curve`. Results are cached per checkpoint in the JSON file, so running it
again after more checkpoints only evaluates the new ones.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys

from ..data.demonstrations import DemonstrationError
from ..evaluation.checkpoints import EvaluationError
from ..evaluation.loss_curve import loss_curve

PROG = "lerobot-ip-loss-curve"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Training and validation loss of every checkpoint of an instant_policy lerobot-train run, "
        "drawn as a PNG.",
    )
    parser.add_argument("--run", required=True, help="the lerobot-train output directory (holds checkpoints/)")
    parser.add_argument("--train-root", required=True, help="root of the training pseudo-demonstration dataset")
    parser.add_argument("--val-root", required=True, help="root of the held-out pseudo-demonstration dataset")
    parser.add_argument("--train-repo-id", help="repo id of the training dataset (default: local/<root name>)")
    parser.add_argument("--val-repo-id", help="repo id of the validation dataset (default: local/<root name>)")
    parser.add_argument("--samples", type=int, default=256, help="frames drawn from each dataset (default 256)")
    parser.add_argument("--batch-size", type=int, default=16, help="frames per forward pass (default 16)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the frame sample and of the diffusion noise")
    parser.add_argument("--device", default="cpu", help="torch device to evaluate on (default cpu)")
    parser.add_argument("--out", required=True, help="the PNG to write, e.g. docs/training_curve.png")
    parser.add_argument("--json", help="per-checkpoint results and cache (default: --out with suffix .json)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # LeRobot prints while loading; stdout carries only the summary
            summary = loss_curve(args.run, args.train_root, args.val_root, args.out, args.json, args.train_repo_id,
                                 args.val_repo_id, args.samples, args.batch_size, args.seed, args.device)
    except (EvaluationError, DemonstrationError, FileNotFoundError, PermissionError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
