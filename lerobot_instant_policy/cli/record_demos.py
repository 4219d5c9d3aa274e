"""``lerobot-ip-record-demos``: scripted demonstrations of ``bullet_tabletop`` tasks as a LeRobotDataset
(``sim.recording``), or of MetaWorld tasks by MetaWorld's scripted experts (``--env metaworld``,
``sim.metaworld.recording``; the ``metaworld`` extra).

    lerobot-ip-record-demos --list-tasks
    lerobot-ip-record-demos --task open_drawer --episodes 2 --out demos/open_drawer --repo-id local/open_drawer --seed 0
    lerobot-ip-record-demos --check --episodes 20 --json      # scripted vs do-nothing success table
    lerobot-ip-record-demos --env metaworld --task pick-place-v3 --episodes 2 --out demos/pick-place-v3 \
        --repo-id local/pick-place-v3 --seed 0
    lerobot-ip-record-demos --demonstrator hand --task pick_and_lift --episodes 2 --out demos/pick_and_lift-hand \
        --repo-id local/pick_and_lift --seed 0

``--demonstrator hand``: a simulated person's hand performs the scripted demonstrations (``sim.hand_demonstrator``);
its RGB-D + landmark recordings are kept in ``OUT-recordings`` and converted into ``OUT`` as a real person's are
(``lerobot-ip-convert-hand``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..sim.env import OBS_TYPES
from ..sim.hand_demonstrator import DEMONSTRATORS, HandDemonstratorConfig, record_hand_demonstrations
from ..sim.recording import IMAGE_KEY, check, check_table, record
from ..sim.task_api import get_task, task_names


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-record-demos", description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", choices=["bullet_tabletop", "metaworld"], default="bullet_tabletop",
                        help="the simulator whose scripted demonstrator records (metaworld: its scripted experts)")
    parser.add_argument("--list-tasks", action="store_true", help="print the task names, one per line")
    parser.add_argument("--check", action="store_true", help="print scripted and do-nothing success per task")
    parser.add_argument("--task", help="task name (--check: a comma-separated list; default all)")
    parser.add_argument("--task-module", help="module to import first (registers user tasks)")
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument("--out", type=Path, help="dataset root to create")
    parser.add_argument("--repo-id", help="dataset repo id, e.g. local/open_drawer")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--with-images", action="store_true", help=f"also write an RGB '{IMAGE_KEY}' key")
    parser.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    parser.add_argument(
        "--obs-type", choices=OBS_TYPES, default="pointcloud", help="segmented clouds or raw depth + joints"
    )
    parser.add_argument("--max-attempts", type=int, default=5, help="seeds tried per episode before giving up")
    parser.add_argument("--demonstrator", choices=DEMONSTRATORS, default="gripper",
                        help="the scripted robot gripper, or a simulated person's hand (converted from its landmarks)")
    hand = HandDemonstratorConfig()
    parser.add_argument("--hand-noise", type=float, default=hand.landmark_noise_m,
                        help="--demonstrator hand: Gaussian noise of every landmark coordinate (m)")
    parser.add_argument("--hand-drop-probability", type=float, default=hand.drop_probability,
                        help="--demonstrator hand: probability that the detector misses the hand in a frame")
    parser.add_argument("--json", action="store_true", help="print JSON (--check, recording)")
    args = parser.parse_args(argv)
    if args.env == "metaworld":
        return _record_metaworld(parser, args)
    if args.list_tasks:
        if args.task_module:
            get_task(task_names()[0], args.task_module)
        print("\n".join(task_names()))
        return 0
    if args.episodes <= 0:
        parser.error("--episodes must be positive")
    if args.check and args.demonstrator != "gripper":
        parser.error("--check runs the scripted gripper only")
    try:
        if args.check:
            tasks = args.task.split(",") if args.task else None
            if tasks:
                for name in tasks:
                    get_task(name, args.task_module)
            else:
                get_task(task_names()[0], args.task_module)
                tasks = task_names()
            rows = check(tasks, args.episodes, args.seed, args.task_module)
            print(json.dumps(rows) if args.json else check_table(rows))
            return 0
        if not (args.task and args.out and args.repo_id):
            parser.error("recording needs --task, --out and --repo-id (or use --list-tasks / --check)")
        get_task(args.task, args.task_module)
        if args.demonstrator == "hand":
            if args.with_images or args.obs_type != "pointcloud":
                parser.error("--demonstrator hand records RGB-D with landmarks itself (no --with-images, --obs-type)")
            config = HandDemonstratorConfig(landmark_noise_m=args.hand_noise,
                                            drop_probability=args.hand_drop_probability)
            summary = record_hand_demonstrations(args.task, args.episodes, args.out, args.repo_id, args.seed, config,
                                                 overwrite=args.overwrite, task_module=args.task_module,
                                                 max_attempts=args.max_attempts)
            print(json.dumps(summary) if args.json else f"wrote {summary['episodes']} hand demonstrations of "
                  f"{args.task} to {args.out} (recordings in {summary['recordings']})")
            return 0
        summary = record(
            args.task,
            args.episodes,
            args.out,
            args.repo_id,
            args.seed,
            with_images=args.with_images,
            overwrite=args.overwrite,
            task_module=args.task_module,
            max_attempts=args.max_attempts,
            obs_type=args.obs_type,
        )
    except (ValueError, FileExistsError, RuntimeError) as error:
        print(f"lerobot-ip-record-demos: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(summary) if args.json else f"wrote {summary['episodes']} episodes of {args.task} to {args.out}")
    return 0


def _record_metaworld(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """``--env metaworld``: record MetaWorld's scripted expert of ``--task``."""
    from ..sim.metaworld.dependencies import MetaworldSetupError
    from ..sim.metaworld.recording import record_expert_demos

    if (args.list_tasks or args.check or args.with_images or args.obs_type != "pointcloud" or args.task_module
            or args.demonstrator != "gripper"):
        parser.error("--env metaworld records segmented clouds of a task only (no --list-tasks, --check, "
                     "--with-images, --obs-type, --task-module or --demonstrator)")
    if not (args.task and args.out and args.repo_id) or args.episodes <= 0:
        parser.error("--env metaworld needs --task, --out, --repo-id and a positive --episodes")
    try:
        summary = record_expert_demos(args.task, args.episodes, args.out, args.repo_id, args.seed,
                                      overwrite=args.overwrite, max_attempts=args.max_attempts)
    except (ValueError, FileExistsError, RuntimeError, MetaworldSetupError) as error:
        print(f"lerobot-ip-record-demos: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(summary) if args.json else f"wrote {summary['episodes']} episodes of {args.task} to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
