"""``lerobot-ip-pretrain-encoder``: occupancy pretraining of the geometry encoder, its evaluation and a picture.

lerobot-ip-pretrain-encoder --preset small --steps 2000 --out outputs/encoder/small.safetensors
lerobot-ip-pretrain-encoder --eval lerobot_instant_policy/assets/encoder/small.safetensors
lerobot-ip-pretrain-encoder --show FILE --object pb/bunny --png encoder.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..model.geometry_encoder import ENCODER_PRESETS, encoder_preset
from ..model.occupancy import load_occupancy_network
from ..pretraining.encoder_pretraining import PretrainConfig, evaluate_weights, pretrain
from ..pretraining.occupancy_picture import draw_occupancy


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-pretrain-encoder", description=__doc__.split("\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--out", type=Path, help="train and write the weights here (.safetensors, plus a .json)")
    mode.add_argument("--eval", type=Path, metavar="FILE", help="print held-out metrics of a weights file as JSON")
    mode.add_argument("--show", type=Path, metavar="FILE", help="draw an object's points, nodes and decoded surface")
    parser.add_argument(
        "--preset",
        choices=sorted(ENCODER_PRESETS),
        help="preset to train (default small); with --eval/--show, refuse weights of another preset",
    )
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--train-scenes", type=int, default=2000)
    parser.add_argument("--eval-scenes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1, help="processes that render the occupancy scenes")
    parser.add_argument("--cache-dir", default="outputs/occupancy_cache")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--no-resume", action="store_true", help="ignore OUT.resume.pt and start over")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--object", default="pb/bunny", help="object id for --show")
    parser.add_argument("--png", type=Path, default=Path("outputs/encoder_occupancy.png"), help="picture for --show")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    expected = encoder_preset(args.preset) if args.preset else None
    config = PretrainConfig(
        preset=args.preset or "small",
        steps=args.steps,
        batch_size=args.batch_size,
        lr=args.lr,
        train_scenes=args.train_scenes,
        eval_scenes=args.eval_scenes,
        seed=args.seed,
        workers=args.workers,
        cache_dir=args.cache_dir,
        device=args.device,
    )
    try:
        if args.out is not None:
            result = pretrain(config, args.out, resume=not args.no_resume, progress=not args.no_progress)
            summary = {"out": str(args.out), **result["held_out"]}
        elif args.eval is not None:
            summary = {"weights": str(args.eval), "split": "held_out", **evaluate_weights(args.eval, config, expected)}
        else:
            summary = draw_occupancy(load_occupancy_network(args.show, expected), args.object, args.png)
    except (ValueError, FileNotFoundError, KeyError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
