"""``python -m workbench.cli.bench`` (from the repository root): the development benchmarks, printed as JSON.

``encoder``: geometry-encoder clouds per second at 2048 points, batch 1 and 16, both presets, and the first layer's
farthest-point sampling on both paths. ``splat --config CONFIG --setting W H SAMPLES ...``: the stream's splatting
settings against a dense pybullet rendering, ms per cloud and distances. ``data --root DIR --repo-id ID``:
milliseconds per training row, LeRobot's delta timestamps against the policy's action table.
``inference --compare-dense-attention|--compare-compile-inference`` and ``train-step --compare-dense-attention|
--compare-frame-cache|--compare-amp|--compare-fused-adamw|--compare-compile-model``: the installed benchmark
(``lerobot-ip-bench inference|train-step``, every flag of theirs too) with that one setting on and off in alternation,
three rounds in one run, their medians and ratio. ``lerobot-train --root DIR``: ``lerobot-train``'s own samples per
second on a dataset, end to end (data loader, LeRobot's loop, the update), for each ``--num-workers`` and
``--omp-wait-policy`` in alternation. The benchmarks themselves are :mod:`workbench.benchmarks`; the ones a user runs
on their own machine (generation, one setting of inference and of the training step, the envs, the stream and the
pool) are the installed ``lerobot-ip-bench``.
"""

from __future__ import annotations

import argparse
import sys

from lerobot_instant_policy.cli.bench import (
    JSON_HELP,
    add_inference_arguments,
    add_train_step_arguments,
    inference_settings,
    run,
    train_step_settings,
)

PROG = "python -m workbench.cli.bench"
#: ``--compare-*`` flags (their argparse names) of ``inference`` and ``train-step``, and the setting each compares.
INFERENCE_COMPARE_FLAGS = {"compare_dense_attention": "dense_attention", "compare_compile_inference": "compile_inference"}
TRAIN_STEP_COMPARE_FLAGS = {
    "compare_dense_attention": "dense_attention",
    "compare_frame_cache": "frame_cache",
    "compare_amp": "use_amp",
    "compare_fused_adamw": "fused_adamw",
    "compare_compile_model": "compile_model",
}
#: What each ``--compare-*`` flag times in alternation (its help).
COMPARE_HELP = {
    "dense_attention": "dense and reference attention",
    "compile_inference": "compiled and eager sampling",
    "frame_cache": "cached and live encoding",
    "use_amp": "autocast and float32",
    "fused_adamw": "fused and loop AdamW",
    "compile_model": "compiled and eager layers",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description="Development benchmarks that print JSON.")
    commands = parser.add_subparsers(dest="command", required=True)
    for add in (_add_encoder, _add_data, _add_splat, _add_inference, _add_train_step, _add_lerobot_train):
        add(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


# ---------------------------------------------------------------------------------------------------- encoder
def _add_encoder(commands) -> None:
    encoder = commands.add_parser("encoder", help="geometry encoder clouds per second (2048 points, CPU)")
    encoder.add_argument("--repeats", type=int, default=5)
    encoder.add_argument("--json", action="store_true", help=JSON_HELP)
    encoder.set_defaults(handler=_run_encoder)


def _run_encoder(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if args.repeats <= 0:
        parser.error("--repeats must be positive")
    from ..benchmarks.encoder import bench_encoder

    return bench_encoder(repeats=args.repeats)


# ---------------------------------------------------------------------------------------------------- data
def _add_data(commands) -> None:
    data = commands.add_parser("data", help="milliseconds per training row: LeRobot's delta timestamps against the "
                                            "policy's action table")
    data.add_argument("--root", required=True, help="a LeRobotDataset in the data contract")
    data.add_argument("--repo-id", required=True)
    data.add_argument("--rows", type=int, default=200)
    data.add_argument("--horizon", type=int, default=8)
    data.add_argument("--repeats", type=int, default=3)
    data.add_argument("--json", action="store_true", help=JSON_HELP)
    data.set_defaults(handler=_run_data)


def _run_data(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if min(args.rows, args.horizon, args.repeats) <= 0:
        parser.error("--rows, --horizon and --repeats must be positive")
    from ..benchmarks.data import bench_data

    return bench_data(args.repo_id, args.root, args.rows, args.horizon, args.repeats)


# ---------------------------------------------------------------------------------------------------- splat
def _add_splat(commands) -> None:
    splat = commands.add_parser("splat", help="the stream's splatting settings: ms per cloud and distance to pybullet")
    splat.add_argument("--config", default="configs/generate/stream_bounded.json")
    splat.add_argument("--setting", nargs=3, type=int, action="append", metavar=("W", "H", "SAMPLES"),
                       help="z-buffer width, height and surface samples per object (repeatable)")
    splat.add_argument("--tasks", type=int, default=4)
    splat.add_argument("--json", action="store_true", help=JSON_HELP)
    splat.set_defaults(handler=_run_splat)


def _run_splat(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if args.tasks <= 0:
        parser.error("--tasks must be positive")
    from lerobot_instant_policy.pseudo_demos.stream import StreamConfig

    from ..benchmarks.splat import bench_splat

    settings = [tuple(setting) for setting in args.setting or [(480, 360, 8192), (240, 180, 4096)]]
    return bench_splat(StreamConfig.from_generate_config(args.config), settings, args.tasks)



# ---------------------------------------------------------------------------------------------------- comparisons
def _add_inference(commands) -> None:
    inference = commands.add_parser("inference", help="lerobot-ip-bench inference with one setting on and off in "
                                                      "alternation (--compare-*), and the ratio")
    add_inference_arguments(inference)
    _add_compare_flags(inference, INFERENCE_COMPARE_FLAGS)
    inference.set_defaults(handler=_run_inference)


def _run_inference(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    compare = _compared_setting(parser, args, INFERENCE_COMPARE_FLAGS)
    settings = inference_settings(parser, args)
    from ..benchmarks.variants import inference_comparison

    return inference_comparison(args.preset, args.repeats, args.policy_path, compare, **settings)


def _add_train_step(commands) -> None:
    train_step = commands.add_parser("train-step", help="lerobot-ip-bench train-step with one setting on and off in "
                                                        "alternation (--compare-*), and the ratio")
    add_train_step_arguments(train_step)
    _add_compare_flags(train_step, TRAIN_STEP_COMPARE_FLAGS)
    train_step.set_defaults(handler=_run_train_step)


def _run_train_step(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    compare = _compared_setting(parser, args, TRAIN_STEP_COMPARE_FLAGS)
    settings = train_step_settings(parser, args)
    from ..benchmarks.variants import train_step_comparison

    return train_step_comparison(args.preset, args.batch_size, args.repeats, compare, **settings)


def _add_compare_flags(parser: argparse.ArgumentParser, flags: dict[str, str]) -> None:
    for flag, setting in flags.items():
        parser.add_argument(f"--{flag.replace('_', '-')}", action="store_true",
                            help=f"time {COMPARE_HELP[setting]} in alternation and report the ratio")


def _compared_setting(parser: argparse.ArgumentParser, args: argparse.Namespace, flags: dict[str, str]) -> str:
    """The setting of the one ``--compare-*`` flag given (``flags``: argparse name → setting); a usage error for none
    (one setting alone: ``lerobot-ip-bench``) or two or more."""
    given = [setting for flag, setting in flags.items() if getattr(args, flag)]
    names = [f"--{flag.replace('_', '-')}" for flag in flags]
    if len(given) != 1:
        parser.error(f"compare one variant at a time: {', '.join(names[:-1])} or {names[-1]} (one setting alone: "
                     f"lerobot-ip-bench {args.command})")
    return given[0]


# ---------------------------------------------------------------------------------------------------- lerobot-train
def _add_lerobot_train(commands) -> None:
    train = commands.add_parser("lerobot-train", help="lerobot-train's own samples per second on a dataset (loader, "
                                                      "loop and update), per loader workers and OpenMP wait policy")
    train.add_argument("--root", required=True, help="a LeRobotDataset in the data contract (frame encodings are "
                                                     "built beside it by the first run when missing)")
    train.add_argument("--repo-id", help="default: local/<the root's name>")
    train.add_argument("--steps", type=int, default=500, help="training steps per run")
    train.add_argument("--skip", type=int, default=200, help="log lines up to this step do not count (warm-up)")
    train.add_argument("--log-every", type=int, default=50, help="--log_freq of each run")
    train.add_argument("--batch-size", type=int, default=8)
    train.add_argument("--threads", type=int, default=2, help="OMP_NUM_THREADS of each run")
    train.add_argument("--num-workers", type=int, nargs="+", default=[1], help="loader workers to compare")
    train.add_argument("--omp-wait-policy", nargs="+", default=["default"], choices=["default", "active", "passive"],
                       help="OMP_WAIT_POLICY values to compare (default: unset)")
    train.add_argument("--compile-model", choices=["true", "false"], default="false",
                       help="--policy.compile_model of every run (compiling falls within --skip)")
    train.add_argument("--rounds", type=int, default=1, help="every variant runs this many times, in alternation")
    train.add_argument("--json", action="store_true", help=JSON_HELP)
    train.set_defaults(handler=_run_lerobot_train)


def _run_lerobot_train(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if min(args.steps, args.log_every, args.batch_size, args.threads, args.rounds) <= 0 or args.skip < 0 \
            or min(args.num_workers) < 0:
        parser.error("--steps, --log-every, --batch-size, --threads and --rounds must be positive, --skip and "
                     "--num-workers >= 0")
    if args.skip >= args.steps:
        parser.error(f"--skip ({args.skip}) must be below --steps ({args.steps})")
    from ..benchmarks.lerobot_train import bench_lerobot_train

    return bench_lerobot_train(args.root, args.repo_id, args.steps, args.skip, args.batch_size, args.log_every,
                               args.threads, tuple(args.num_workers), tuple(args.omp_wait_policy),
                               args.compile_model == "true", args.rounds)


if __name__ == "__main__":
    sys.exit(main())
