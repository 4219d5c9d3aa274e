"""``lerobot-ip-eval-metaworld``: record MetaWorld expert demonstration sets and run ``lerobot-eval`` in
``--env.type=metaworld_pointcloud`` on MetaWorld tasks, then print the success table with cluster (over tasks) and
per-episode 95% intervals (``evaluation.suite``, ``evaluation.metaworld_suite``, ``evaluation.success_table``).

  lerobot-ip-eval-metaworld --policy metaworld_expert --episodes 10                  (MT10, the upper bound)
  lerobot-ip-eval-metaworld --policy instant_policy --policy-path CKPT --tasks pick-place-v3,reach-v3
  lerobot-ip-eval-metaworld --policy demo_replay --demo-sets 3 --out outputs/eval_metaworld
  lerobot-ip-eval-metaworld --policy instant_policy --policy-path CKPT --swap   (each task reads another kind's demos)

It takes the arguments of ``lerobot-ip-eval-suite`` (``evaluation.suite_command``) but ``--task-module``,
``--obs-type`` and ``--success``, and adds ``--episode-length`` and ``--pointcloud-every``.
"""

from __future__ import annotations

import argparse
import sys

from ..evaluation import suite_command
from ..evaluation.suite_command import METAWORLD


def build_parser() -> argparse.ArgumentParser:
    return suite_command.build_parser("lerobot-ip-eval-metaworld", __doc__.split("\n\n")[0], METAWORLD)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    return suite_command.run_command(parser.prog, METAWORLD, parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
