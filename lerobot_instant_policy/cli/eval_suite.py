"""``lerobot-ip-eval-suite``: record demonstration sets and run ``lerobot-eval`` on ``bullet_tabletop`` tasks, then
print the success table with cluster (over tasks) and per-episode 95% intervals (``evaluation.suite``,
``evaluation.success_table``).

  lerobot-ip-eval-suite --policy demo_replay --episodes 10 --demo-sets 3 --out outputs/eval_suite
  lerobot-ip-eval-suite --policy instant_policy --policy-path CKPT/pretrained_model --tasks open_drawer,push_button
  lerobot-ip-eval-suite --policy instant_policy --policy-path CKPT --swap    (each task with another group's demos)
  lerobot-ip-eval-suite --policy demo_replay --split test                   (the held-out seeds: once per candidate)
  lerobot-ip-eval-suite --policy do_nothing --episodes 10 --out outputs/eval_suite   (no demonstrations recorded)
  lerobot-ip-eval-suite --policy demo_replay --obs-type rgbd --env-arg depth_noise_std=0.002 --run-name noisy
  lerobot-ip-eval-suite --policy demo_replay --demonstrator hand --run-name demo_replay-hand   (hand demonstrations)

``--obs-type rgbd`` runs the real-robot path: demonstrations are recorded as raw depth + joint states and
converted with ``lerobot-ip-convert``'s pipeline, and the env hands out depth only (``--env.obs_type=rgbd``), which
its env preprocessor turns into segmented clouds. ``--env-arg KEY=VALUE`` sets ``--env.KEY=VALUE`` (sensor noise,
calibration error) for the evaluation only; demonstrations are always recorded clean. The arguments, shared with
``lerobot-ip-eval-metaworld``, and the run are ``evaluation.suite_command``'s.
"""

from __future__ import annotations

import argparse
import sys

from ..evaluation import suite_command
from ..evaluation.suite_command import BULLET_TABLETOP


def build_parser() -> argparse.ArgumentParser:
    return suite_command.build_parser("lerobot-ip-eval-suite", __doc__.split("\n\n")[0], BULLET_TABLETOP)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    return suite_command.run_command(parser.prog, BULLET_TABLETOP, parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
