"""``lerobot-ip-train-language``: train a language head for an ``instant_policy`` checkpoint on demonstration datasets
whose tasks have paraphrases, and measure it on held-out sentences and held-out episodes.

1. The targets of every dataset (:mod:`..language.targets`: each episode live once, the N next ones of its task in
   context, ``--frames-per-episode`` frames of it), kept under ``OUT/targets/`` and reused when built the same way.
2. Each task's last live episodes (``--val-fraction`` of them, at least one kept for training) are held out.
3. The head trains on the rest with the seen paraphrases (:func:`..language.training.train_language_head`).
4. Measured (:func:`..language.training.evaluate_language_head`): on the training frames with the seen and with the
   held-out sentences, on the held-out episodes with the held-out sentences, and there also a head of the same seed
   that was never trained (the reference a trained head must beat).

Output ``OUT/``: ``head/`` (``config.json`` + ``model.safetensors``,
:meth:`..language.language_head.LanguageHead.load`), ``metrics.json`` (the settings, the tasks and frame counts, the
loss history, the evaluations, the seconds spent) and ``targets/``. Prints the evaluations as JSON on stdout and a
summary line on stderr; exit status 2 when the inputs are refused (with the reason on stderr).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import torch

from ..configuration_instant_policy import SHIPPED_CHECKPOINT
from ..data.demonstrations import DemonstrationError
from ..evaluation.checkpoints import EvaluationError, load_policy
from ..language.language_head import HeadBinding, LanguageHead, LanguageHeadConfig, LanguageHeadError
from ..language.paraphrases import PARAPHRASES_FILE, ParaphraseError, Paraphrases
from ..language.text_encoder import DEFAULT_TEXT_ENCODER, SPEC_FORMS, TextEncoderError, make_text_encoder
from ..training.language_head_training import TrainSettings, evaluate_language_head, train_language_head
from ..training.language_targets import LanguageTargets, TargetsError, cached_targets

PROG = "lerobot-ip-train-language"
# every refusal of the inputs is one of these (ValueError subclasses) or a missing file
REFUSED = (DemonstrationError, EvaluationError, LanguageHeadError, ParaphraseError, TargetsError, TextEncoderError,
           ValueError, FileNotFoundError)


def build_parser() -> argparse.ArgumentParser:
    head, train = LanguageHeadConfig(), TrainSettings()
    parser = argparse.ArgumentParser(prog=PROG, description="Train a language head that predicts an instant_policy "
                                     "checkpoint's bottleneck from the observation and a sentence (paper §4.3).")
    parser.add_argument("--dataset", action="append", required=True, type=Path, metavar="ROOT",
                        help="a demonstration dataset (LeRobotDataset in the data contract, repo id local/<name>); "
                             "repeat for several")
    parser.add_argument("--out", required=True, type=Path, help="output directory")
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_CHECKPOINT,
                        help="instant_policy pretrained_model directory (default: the shipped one)")
    parser.add_argument("--text-encoder", default=DEFAULT_TEXT_ENCODER, help=f"{SPEC_FORMS} (default %(default)s)")
    parser.add_argument("--paraphrases", type=Path, default=PARAPHRASES_FILE,
                        help="paraphrase file (default: the shipped one, both suites)")
    parser.add_argument("--tasks", help="comma-separated tasks to read of every dataset (default: all)")
    parser.add_argument("--num-demos", type=int, default=2, help="demonstrations in context, N (default %(default)s)")
    parser.add_argument("--frames-per-episode", type=int, default=16,
                        help="frames of each live episode, spread evenly (default %(default)s)")
    parser.add_argument("--val-fraction", type=float, default=0.2,
                        help="fraction of each task's episodes held out (default %(default)s)")
    parser.add_argument("--steps", type=int, default=train.steps, help="optimiser steps (default %(default)s)")
    parser.add_argument("--batch-size", type=int, default=train.batch_size, help="default %(default)s")
    parser.add_argument("--lr", type=float, default=train.lr, help="default %(default)s")
    parser.add_argument("--seed", type=int, default=train.seed, help="default %(default)s")
    parser.add_argument("--num-layers", type=int, default=head.num_layers, help="default %(default)s")
    parser.add_argument("--temperature", type=float, default=head.temperature, help="default %(default)s")
    parser.add_argument("--contrastive-weight", type=float, default=head.contrastive_weight,
                        help="default %(default)s (the regression's weight is 1)")
    parser.add_argument("--device", default="cpu")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        result = run(args)
    except REFUSED as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(result["evaluation"], indent=2))
    held = result["evaluation"].get("held_out_episodes")
    where = held or result["evaluation"]["train_held_out_sentences"]
    frames = "held-out episodes" if held else "training frames"
    print(f"{PROG}: {result['frames']['train']} training frames of {len(result['tasks'])} tasks, "
          f"{result['history'][-1]['loss']:.4f} loss at the end; on {frames} with held-out sentences: ranking "
          f"{where['ranking_top1']:.3f} (chance {where['ranking_chance']:.3f}), cosine {where['cosine']:.3f}, MSE "
          f"{where['mse']:.4f} (the task's mean target {where['mse_task_mean']:.4f}); head in {args.out / 'head'}",
          file=sys.stderr)
    return 0


def run(args: argparse.Namespace) -> dict:
    """The command's work (module docstring) → the record written to ``OUT/metrics.json``."""
    start = time.perf_counter()
    settings = TrainSettings(steps=args.steps, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                             device=args.device)
    config = LanguageHeadConfig(num_layers=args.num_layers, temperature=args.temperature,
                                contrastive_weight=args.contrastive_weight)
    text_encoder = make_text_encoder(args.text_encoder)
    paraphrases = Paraphrases.load(args.paraphrases)
    policy = load_policy(args.checkpoint, args.device)
    tasks = [task.strip() for task in args.tasks.split(",") if task.strip()] if args.tasks else None
    train_parts, held_parts = [], []
    for number, root in enumerate(args.dataset):
        targets = cached_targets(args.out / "targets" / f"{number}-{root.name}", policy, root,
                                 num_demos=args.num_demos, frames_per_episode=args.frames_per_episode, tasks=tasks,
                                 paraphrases=paraphrases)
        train_part, held_part = targets.split_episodes(args.val_fraction)
        train_parts.append(train_part)
        held_parts.append(held_part)
    train_targets, held_targets = LanguageTargets.concatenate(train_parts), LanguageTargets.concatenate(held_parts)
    targets_seconds = time.perf_counter() - start
    trained = train_language_head(policy.network, train_targets, paraphrases, text_encoder, config, settings,
                                  on_log=lambda entry: print(f"{PROG}: {json.dumps(entry)}", file=sys.stderr))
    train_seconds = time.perf_counter() - start - targets_seconds
    trained.head.save(args.out / "head")
    network = policy.network

    def evaluate(head: LanguageHead, targets: LanguageTargets, split: str) -> dict:
        return evaluate_language_head(head, network, targets, paraphrases, text_encoder, split)

    evaluation = {"train_seen_sentences": evaluate(trained.head, train_targets, "seen"),
                  "train_held_out_sentences": evaluate(trained.head, train_targets, "held_out")}
    if held_targets.num_frames:
        evaluation["held_out_episodes"] = evaluate(trained.head, held_targets, "held_out")
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(args.seed)
            untrained = LanguageHead(config, HeadBinding.of(network, text_encoder)).to(settings.device).eval()
        evaluation["held_out_episodes_untrained_head"] = evaluate(untrained, held_targets, "held_out")
    result = {
        "checkpoint": str(args.checkpoint), "datasets": [str(root) for root in args.dataset],
        "text_encoder": text_encoder.spec, "paraphrases": str(args.paraphrases), "num_demos": args.num_demos,
        "frames_per_episode": args.frames_per_episode, "val_fraction": args.val_fraction,
        "config": dataclasses.asdict(config), "settings": dataclasses.asdict(settings),
        "tasks": train_targets.tasks,
        "frames": {"train": train_targets.num_frames, "held_out_episodes": held_targets.num_frames},
        "history": trained.history, "evaluation": evaluation,
        "seconds": {"targets": round(targets_seconds, 1), "training": round(train_seconds, 1),
                    "total": round(time.perf_counter() - start, 1)},
    }
    (args.out / "metrics.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    sys.exit(main())
