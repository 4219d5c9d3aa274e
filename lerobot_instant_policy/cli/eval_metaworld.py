"""``lerobot-ip-eval-metaworld``: record MetaWorld expert demonstration sets and run ``lerobot-eval`` in
``--env.type=metaworld_pointcloud`` on MetaWorld tasks, then print the success table with cluster (over tasks) and
per-episode 95% intervals (``evaluation.suite``, ``evaluation.metaworld_suite``, ``evaluation.success_table``).

  lerobot-ip-eval-metaworld --policy metaworld_expert --episodes 10                  (MT10, the upper bound)
  lerobot-ip-eval-metaworld --policy instant_policy --policy-path CKPT --tasks pick-place-v3,reach-v3
  lerobot-ip-eval-metaworld --policy demo_replay --demo-sets 3 --out outputs/eval_metaworld
  lerobot-ip-eval-metaworld --policy instant_policy --policy-path CKPT --swap   (each task reads another kind's demos)
"""

from __future__ import annotations

import argparse
import sys

from ..evaluation import metaworld_suite
from ..sim.metaworld.configuration_metaworld import resolve_tasks
from .eval_suite import add_suite_arguments, run, suite_settings


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-eval-metaworld", description=__doc__.split("\n\n")[0])
    add_suite_arguments(parser, metaworld_suite.POLICIES, "mt10", "comma-separated task names or groups: mt10, mt50, "
                        "ml45_train, ml45_test, easy … very_hard", 1, "outputs/eval_metaworld")
    parser.add_argument("--episode-length", type=int, default=metaworld_suite.DEFAULT_EPISODE_LENGTH,
                        help="step limit per episode (MetaWorld's: 500)")
    parser.add_argument("--pointcloud-every", type=int, default=metaworld_suite.DEFAULT_POINTCLOUD_EVERY,
                        help="render clouds every this many steps and after gripper changes (8: what instant_policy reads)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    return run(parser.prog, lambda: (
        suite_settings(args, env_type=metaworld_suite.ENV_TYPE, episode_length=args.episode_length,
                       pointcloud_every=args.pointcloud_every),
        resolve_tasks(args.tasks),
    ))


if __name__ == "__main__":
    sys.exit(main())
