"""``lerobot-ip-generate``: write a pseudo-demonstration LeRobotDataset (and optionally its preview picture)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from ..config_io import load_config
from ..objects.rendering import CLOUD_SOURCES, RENDERERS
from ..pseudo_demos.generation import GenerationConfig, generate_dataset
from ..pseudo_demos.tasks import FAMILIES


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lerobot-ip-generate",
        description="Generate pseudo-demonstrations (Instant Policy §3.3) as a LeRobotDataset v3.",
    )
    parser.add_argument("--config", help="JSON file with GenerationConfig fields (e.g. configs/generate/default.json)")
    parser.add_argument("--out", help="output directory (the dataset root)")
    parser.add_argument("--repo-id", help="dataset repo id, e.g. local/pseudo_demos")
    parser.add_argument("--num-tasks", type=int, help="number of pseudo-tasks")
    parser.add_argument("--first-task", type=int,
                        help="index of the first pseudo-task (default 0): the dataset holds tasks FIRST … FIRST + "
                             "NUM_TASKS − 1 of the seed, as the pseudo-task stream draws them")
    parser.add_argument("--demos-per-task", type=int, help="demonstrations per pseudo-task")
    parser.add_argument("--workers", type=int, help="parallel worker processes")
    parser.add_argument("--seed", type=int, help="random seed; the same seed gives the same dataset")
    parser.add_argument("--tasks-per-shard", type=int, help="tasks per resumable shard")
    parser.add_argument("--object-split", choices=["train", "held_out", "all"], help="object library split to draw from")
    parser.add_argument("--objects", nargs="+", metavar="ID", help="draw objects only from these ids (e.g. pb/mug urdf/001)")
    parser.add_argument("--family", choices=list(FAMILIES), help="rung of the pseudo-task ladder (default: full)")
    parser.add_argument("--tasks-per-object-group", type=int, help="consecutive tasks that share their two objects")
    parser.add_argument("--cloud", choices=list(CLOUD_SOURCES),
                        help="cameras: rendered segmented depth (default); surface: complete object surface samples")
    parser.add_argument("--renderer", choices=list(RENDERERS),
                        help="what renders the cameras' clouds: pybullet (default) or splat (the pseudo-task "
                             "stream's z-buffer splatting, on the CPU)")
    parser.add_argument("--share-object-layout", action="store_true",
                        help="every demonstration of a task places the objects as its first one (only the start "
                             "differs): --shared-layout-fraction 1")
    parser.add_argument("--shared-layout-fraction", type=float, metavar="P",
                        help="the fraction of tasks whose demonstrations share one object layout (default 0: objects "
                             "move between demonstrations, the paper's setting)")
    parser.add_argument("--layout-shift", type=float, metavar="F",
                        help="in the other tasks, how far each later demonstration moves the objects from the first's "
                             "poses towards a fresh layout (default 1: an independent draw, the paper's setting)")
    parser.add_argument("--object-max-yaw-deg", type=float,
                        help="objects turn about the vertical by at most this many degrees (default: 180)")
    parser.add_argument("--start-max-roll-deg", type=float,
                        help="the gripper's start pose turns about its approach axis by at most this (default: 90)")
    parser.add_argument("--waypoint-max-roll-deg", type=float,
                        help="every gripper pose of a task turns about its approach axis by at most this (default: 180)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    parser.add_argument("--resume", action="store_true", help="continue an interrupted generation in --out")
    parser.add_argument("--keep-shards", action="store_true", help="keep the per-shard datasets after merging")
    parser.add_argument("--preview", metavar="FILE.png", help="also draw the first pseudo-tasks' demonstrations")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def config_from_args(args: argparse.Namespace) -> GenerationConfig:
    config = load_config(GenerationConfig, args.config) if args.config else GenerationConfig()
    overrides = {
        "out": args.out,
        "repo_id": args.repo_id,
        "num_tasks": args.num_tasks,
        "first_task": args.first_task,
        "demos_per_task": args.demos_per_task,
        "workers": args.workers,
        "seed": args.seed,
        "tasks_per_shard": args.tasks_per_shard,
        "object_split": args.object_split,
        "object_pool": args.objects,
        "family": args.family,
        "tasks_per_object_group": args.tasks_per_object_group,
        "waypoint_max_roll_deg": args.waypoint_max_roll_deg,
    }
    config = dataclasses.replace(config, **{key: value for key, value in overrides.items() if value is not None})
    render_overrides = {key: value for key, value in (("cloud", args.cloud), ("renderer", args.renderer)) if value}
    if render_overrides:
        config = dataclasses.replace(config, render=dataclasses.replace(config.render, **render_overrides))
    demo_overrides = {
        "shared_layout_fraction": 1.0 if args.share_object_layout else args.shared_layout_fraction,
        "layout_shift": args.layout_shift,
        "object_max_yaw_deg": args.object_max_yaw_deg,
        "start_max_roll_deg": args.start_max_roll_deg,
    }
    demo_overrides = {key: value for key, value in demo_overrides.items() if value is not None}
    if demo_overrides:
        config = dataclasses.replace(config, demo=dataclasses.replace(config.demo, **demo_overrides))
    return config


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.share_object_layout and args.shared_layout_fraction is not None:
        print("lerobot-ip-generate: error: --share-object-layout is --shared-layout-fraction 1; pass one of them",
              file=sys.stderr)
        return 2
    try:
        config = config_from_args(args)
        out = generate_dataset(
            config, overwrite=args.overwrite, resume=args.resume, keep_shards=args.keep_shards, progress=not args.no_progress
        )
    except (ValueError, KeyError, FileExistsError, FileNotFoundError, PermissionError) as error:
        print(f"lerobot-ip-generate: error: {error}", file=sys.stderr)
        return 2
    print(f"wrote {config.num_tasks * config.demos_per_task} pseudo-demonstrations to {out}")
    if args.preview:
        from lerobot.datasets import LeRobotDataset

        from ..pseudo_demos.preview import draw_preview, load_preview_episodes

        dataset = LeRobotDataset(config.repo_id, root=out)
        picture = draw_preview(load_preview_episodes(dataset, num_tasks=2, demos_per_task=3), args.preview)
        print(f"preview: {picture}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
