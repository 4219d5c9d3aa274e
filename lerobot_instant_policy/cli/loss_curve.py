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
from pathlib import Path

from ..data.demonstrations import DemonstrationError
from ..evaluation.loss_curve import (
    LossCurveCache,
    LossCurveError,
    checkpoint_config,
    draw_loss_curve,
    evaluate_loss,
    find_checkpoints,
    load_checkpoint,
    load_evaluation_set,
    prior_only_loss,
    weights_fingerprint,
)

PROG = "lerobot-ip-loss-curve"
LABELS = {"train": "training", "val": "validation (held-out)", "val_swap": "held-out, swapped context"}


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


def picture_title(run_dir: Path, datasets: dict[str, dict]) -> str:
    sizes = "; ".join(
        f"{LABELS[name]}: {info['tasks']} pseudo-tasks, {info['episodes']} episodes, {info['frames']} frames"
        for name, info in datasets.items()
    )
    samples = ", ".join(f"{info['samples']} {LABELS[name].split()[0]}" for name, info in datasets.items())
    return f"Instant Policy training curve, run {run_dir}\n{sizes}\nloss on fixed frames ({samples})"


def run(args: argparse.Namespace) -> dict:
    """Evaluate the checkpoints not in the cache, save the cache and the PNG; return the summary."""
    checkpoints = find_checkpoints(args.run)
    config = checkpoint_config(checkpoints[-1])
    evaluations = {
        "train": load_evaluation_set("train", args.train_root, config, args.samples, args.seed, args.train_repo_id),
        "val": load_evaluation_set("val", args.val_root, config, args.samples, args.seed, args.val_repo_id),
    }
    descriptions = {name: evaluation.describe() for name, evaluation in evaluations.items()}
    json_path = Path(args.json) if args.json else Path(args.out).with_suffix(".json")
    settings = {"samples": args.samples, "batch_size": args.batch_size, "seed": args.seed}
    cache = LossCurveCache(json_path, settings, descriptions)
    evaluated, reused = [], []
    prior = cache.prior
    steps = [checkpoint.step for checkpoint in checkpoints]
    for checkpoint in checkpoints:
        weights = weights_fingerprint(checkpoint)
        if cache.get(checkpoint.step, weights) is not None:
            reused.append(checkpoint.step)
            continue
        policy, preprocessor = load_checkpoint(checkpoint, args.device)
        for name in ("num_waypoints", "horizon", "num_points"):
            if getattr(policy.config, name) != getattr(config, name):
                raise LossCurveError(
                    f"checkpoint {checkpoint.path} has {name}={getattr(policy.config, name)}, the run's last "
                    f"checkpoint {getattr(config, name)}: evaluate runs with one data layout"
                )
        results = {name: evaluate_loss(policy, preprocessor, evaluation, args.batch_size, args.seed)
                   for name, evaluation in evaluations.items()}
        results["val_swap"] = evaluate_loss(policy, preprocessor, evaluations["val"], args.batch_size, args.seed,
                                            swap_context=True)
        if prior is None:
            prior = prior_only_loss(policy, preprocessor, evaluations["val"], args.batch_size, args.seed)
        cache.prior = prior
        cache.put(checkpoint.step, weights, results)
        cache.save(steps)
        evaluated.append(checkpoint.step)
        print(f"step {checkpoint.step}: " + ", ".join(f"{name} loss {result.loss:.4f}"
                                                     for name, result in results.items()), file=sys.stderr)
    cache.save(steps)
    entries = [cache.entries[step] for step in steps]
    lines = {**descriptions, "val_swap": descriptions["val"]}
    levels = {"prior-only translation, held-out": prior["translation"]} if prior else None
    picture = draw_loss_curve(entries, lines, LABELS, args.out, picture_title(Path(args.run), descriptions), levels)
    best = min(entries, key=lambda entry: entry["val"]["loss"])
    return {
        "run": str(args.run),
        "png": str(picture),
        "json": str(json_path),
        "datasets": descriptions,
        "settings": settings,
        "cache_discarded": cache.discarded,
        "evaluated": evaluated,
        "reused": reused,
        "prior_only_val": prior,
        "curve": [{"step": entry["step"], "train_loss": entry["train"]["loss"], "val_loss": entry["val"]["loss"],
                   "val_translation": entry["val"]["translation"],
                   "val_swap_translation": entry.get("val_swap", {}).get("translation"),
                   "context_gain_translation": _gain(entry, "translation"),
                   "context_gain_rotation": _gain(entry, "rotation")}
                  for entry in entries],
        "best_val": {"step": best["step"], "val_loss": best["val"]["loss"]},
    }


def _gain(entry: dict, part: str) -> float | None:
    """Held-out loss with a swapped context / with the frame's own context (``None`` for an entry without a swap)."""
    if "val_swap" not in entry or entry["val"][part] <= 0:
        return None
    return round(entry["val_swap"][part] / entry["val"][part], 3)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # LeRobot prints while loading; stdout carries only the summary
            summary = run(args)
    except (LossCurveError, DemonstrationError, FileNotFoundError, PermissionError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
