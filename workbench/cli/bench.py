"""``python -m workbench.cli.bench`` (from the repository root): the development benchmarks, printed as JSON.

``encoder``: geometry-encoder clouds per second at 2048 points, batch 1 and 16, both presets, and the first layer's
farthest-point sampling on both paths. ``splat --config CONFIG --setting W H SAMPLES ...``: the stream's splatting
settings against a dense pybullet rendering, ms per cloud and distances. ``data --root DIR --repo-id ID``: milliseconds per training row, LeRobot's
delta timestamps against the policy's action table. The benchmarks themselves are :mod:`workbench.benchmarks`; the
ones a user runs on their own machine (generation, inference, training step, ``lerobot-train``, the envs) are the
installed ``lerobot-ip-bench``.
"""

from __future__ import annotations

import argparse
import sys

from lerobot_instant_policy.cli.bench import JSON_HELP, run

PROG = "python -m workbench.cli.bench"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description="Development benchmarks that print JSON.")
    commands = parser.add_subparsers(dest="command", required=True)
    for add in (_add_encoder, _add_data, _add_splat):
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


if __name__ == "__main__":
    sys.exit(main())
