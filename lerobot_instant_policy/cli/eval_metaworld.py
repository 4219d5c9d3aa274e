"""``lerobot-ip-eval-metaworld``: record MetaWorld expert demonstration sets and run ``lerobot-eval`` in
``--env.type=metaworld_pointcloud`` on MetaWorld tasks, then print the success table with Wilson 95% intervals
(``evaluation.metaworld_suite``, ``evaluation.success_table``).

  lerobot-ip-eval-metaworld --policy metaworld_expert --episodes 10                  (MT10, the upper bound)
  lerobot-ip-eval-metaworld --policy instant_policy --policy-path CKPT --tasks pick-place-v3,reach-v3
  lerobot-ip-eval-metaworld --policy demo_replay --demo-sets 3 --out outputs/eval_metaworld
  lerobot-ip-eval-metaworld --policy instant_policy --policy-path CKPT --swap   (each task reads another kind's demos)
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from ..evaluation.metaworld_suite import ENV_TYPE, POLICIES, MetaworldSuiteSettings, run_suite
from ..evaluation.success_table import collect_results, format_table, write_table
from ..evaluation.suite import SuiteError
from .eval_suite import add_seed_arguments, seeds
from ..sim.metaworld.configuration_metaworld import resolve_tasks
from ..sim.metaworld.dependencies import MetaworldSetupError


def policy_arg(text: str) -> str:
    """``KEY=VALUE`` → ``--policy.KEY=VALUE``."""
    key, separator, value = text.partition("=")
    if not separator or not key or not value:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with a policy config field as KEY, got {text!r}")
    return f"--policy.{key}={value}"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-eval-metaworld", description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", choices=POLICIES, default="demo_replay")
    parser.add_argument("--policy-path", help="a pretrained_model directory (instant_policy checkpoints)")
    parser.add_argument("--tasks", default="mt10",
                        help="comma-separated task names or groups: mt10, mt50, ml45_train, ml45_test, easy … very_hard")
    parser.add_argument("--episodes", type=int, default=10, help="evaluation episodes per task and demonstration set")
    parser.add_argument("--demo-sets", type=int, default=1, help="disjoint demonstration sets per task")
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--num-demos", type=int, default=2)
    add_seed_arguments(parser)
    parser.add_argument("--episode-length", type=int, default=200, help="step limit per episode (MetaWorld's: 500)")
    parser.add_argument("--pointcloud-every", type=int, default=8,
                        help="render clouds every this many steps and after gripper changes (8: what instant_policy reads)")
    parser.add_argument("--out", type=Path, default=Path("outputs/eval_metaworld"))
    parser.add_argument("--swap", action="store_true",
                        help="the context-swap control: each task reads the demonstrations of a task that asks for "
                             "something else, relabelled")
    parser.add_argument("--policy-arg", dest="policy_args", type=policy_arg, action="append", default=[],
                        metavar="KEY=VALUE", help="override a policy config field (repeatable; --policy.KEY=VALUE)")
    parser.add_argument("--run-name", help="name of this run's folder under OUT/runs and of its table (default: the "
                                           "policy, with -swap for --swap)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the cells of OUT/runs/<name> already evaluated with the same settings and evaluate "
                             "the rest (refused if a finished cell's settings differ)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.run_name is not None and not re.fullmatch(r"[\w.-]+", args.run_name):
        parser.error(f"--run-name must be a plain folder name (letters, digits, '_', '-', '.'), got {args.run_name!r}")
    try:
        settings = MetaworldSuiteSettings(
            policy=args.policy, policy_path=args.policy_path, tasks=tuple(resolve_tasks(args.tasks)), out=args.out,
            episodes=args.episodes, demo_sets=args.demo_sets, batch_size=args.batch_size, num_demos=args.num_demos,
            episode_length=args.episode_length, **seeds(args),
            pointcloud_every=args.pointcloud_every, policy_args=tuple(args.policy_args),
            swap=args.swap, run_name=args.run_name, resume=args.resume,
        )
        runs = run_suite(settings, report=lambda line: print(line, flush=True))
    except (SuiteError, MetaworldSetupError, ValueError, RuntimeError, FileExistsError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    name = settings.name
    results = collect_results([f"{name}={run}" for run in runs], None, ENV_TYPE)
    json_path, png_path = write_table(results, args.out / f"success_table_{name}",
                                      title=f"MetaWorld: {name}, success per task")
    print(format_table(results))
    print(f"\nwrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
