"""``lerobot-ip-eval-suite``: record demonstration sets and run ``lerobot-eval`` on ``bullet_tabletop`` tasks, then
print the success table with Wilson 95% intervals (``evaluation.suite``, ``evaluation.success_table``).

  lerobot-ip-eval-suite --policy demo_replay --episodes 10 --demo-sets 3 --out outputs/eval_suite
  lerobot-ip-eval-suite --policy instant_policy --policy-path CKPT/pretrained_model --tasks open_drawer,push_button
  lerobot-ip-eval-suite --policy instant_policy --policy-path CKPT --swap    (each task with another group's demos)
  lerobot-ip-eval-suite --policy demo_replay --split test                   (the held-out seeds: once per candidate)
  lerobot-ip-eval-suite --policy do_nothing --episodes 10 --out outputs/eval_suite   (no demonstrations recorded)
  lerobot-ip-eval-suite --policy demo_replay --obs-type rgbd --env-arg depth_noise_std=0.002 --run-name noisy

``--obs-type rgbd`` runs the real-robot path: demonstrations are recorded as raw depth + joint states and
converted with ``lerobot-ip-convert``'s pipeline, and the env hands out depth only (``--env.obs_type=rgbd``), which
its env preprocessor turns into segmented clouds. ``--env-arg KEY=VALUE`` sets ``--env.KEY=VALUE`` (sensor noise,
calibration error) for the evaluation only; demonstrations are always recorded clean.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from ..evaluation.success_table import DEFAULT_ENV_TYPE, collect_results, format_table, write_table
from ..evaluation.suite import POLICIES, SEED_SPLITS, SUCCESS_CRITERIA, SuiteError, SuiteSettings, run_suite
from ..sim.env import OBS_TYPES
from ..sim.task_api import get_task, task_names


def parse_policy_arg(text: str, prefix: str = "policy") -> str:
    """``KEY=VALUE`` → ``--policy.KEY=VALUE`` (a policy config field overridden for the evaluation)."""
    key, separator, value = text.partition("=")
    if not separator or not key or not value or not key.replace("_", "").replace(".", "").isalnum():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with a {prefix} config field as KEY, got {text!r}")
    return f"--{prefix}.{key}={value}"


def parse_env_arg(text: str) -> str:
    """``KEY=VALUE`` → ``--env.KEY=VALUE`` (an env config field set for the evaluation)."""
    return parse_policy_arg(text, prefix="env")


def build_parser(prog: str = "lerobot-ip-eval-suite") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", choices=POLICIES, default="demo_replay")
    parser.add_argument("--policy-path", help="a pretrained_model directory (instant_policy checkpoints)")
    parser.add_argument("--tasks", default="all", help="comma-separated task names, or 'all'")
    parser.add_argument("--task-module", help="module that registers user tasks")
    parser.add_argument("--episodes", type=int, default=10, help="evaluation episodes per task and demonstration set")
    parser.add_argument("--demo-sets", type=int, default=3,
                        help="disjoint demonstration sets per task, each recorded on its own seeds (default 3)")
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--num-demos", type=int, default=2)
    add_seed_arguments(parser)
    parser.add_argument("--swap", action="store_true",
                        help="the context-swap control: each task reads the demonstrations of a task of another group, "
                             "relabelled")
    parser.add_argument("--out", type=Path, default=Path("outputs/eval_suite"))
    parser.add_argument("--policy-arg", dest="policy_args", type=parse_policy_arg, action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a policy config field, e.g. inference_steps=8 (repeatable; --policy.KEY=VALUE)")
    parser.add_argument("--obs-type", choices=OBS_TYPES, default="pointcloud",
                        help="segmented clouds from the simulator, or raw depth through the perception pipeline")
    parser.add_argument("--env-arg", dest="env_args", type=parse_env_arg, action="append", default=[],
                        metavar="KEY=VALUE",
                        help="set an env config field for the evaluation, e.g. depth_noise_std=0.002 (repeatable)")
    parser.add_argument("--success", choices=SUCCESS_CRITERIA, default="held",
                        help="held: the goal state must hold for the task's hold time (default); instant: the first "
                             "step in the goal state counts (the criterion of figures before 2026-11-26)")
    parser.add_argument("--run-name", help="name of this run's folder under OUT/runs and of its table (default: the "
                                           "policy, with -swap for --swap)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the cells of OUT/runs/<name> already evaluated with the same settings and evaluate "
                             "the rest (refused if a finished cell's settings differ)")
    return parser


def add_seed_arguments(parser: argparse.ArgumentParser) -> None:
    """``--split`` and the seeds it sets, which ``--demo-seed`` / ``--eval-seed`` override (``seeds``)."""
    parser.add_argument("--split", choices=sorted(SEED_SPLITS), default="dev",
                        help="dev: the seeds every study and option choice uses (demonstrations from 0, episodes from "
                             "1000); test: held out, run once per shipped candidate (from 50000 and 60000)")
    parser.add_argument("--demo-seed", type=int, default=None, help="set s records from seed DEMO_SEED + 100 s "
                                                                     "(default: the split's)")
    parser.add_argument("--eval-seed", type=int, default=None, help="set s evaluates seeds EVAL_SEED + EPISODES s … "
                                                                     "(default: the split's)")


def seeds(args: argparse.Namespace) -> dict:
    """``demo_seed``, ``eval_seed`` and ``split`` from ``--split`` and the overrides (``split`` is ``custom`` when
    an override moves a seed off the split's)."""
    demo_seed, eval_seed = SEED_SPLITS[args.split]
    demo_seed = demo_seed if args.demo_seed is None else args.demo_seed
    eval_seed = eval_seed if args.eval_seed is None else args.eval_seed
    split = args.split if (demo_seed, eval_seed) == SEED_SPLITS[args.split] else "custom"
    return {"demo_seed": demo_seed, "eval_seed": eval_seed, "split": split}


def resolve_tasks(text: str, task_module: str | None) -> list[str]:
    """``all`` (the registered tasks, after importing ``task_module``) or the comma-separated names, each checked."""
    if text == "all":
        if task_module:
            get_task(task_names()[0], task_module)  # imports the module, registering its tasks
        return task_names()
    names = [name.strip() for name in text.split(",") if name.strip()]
    for name in names:
        get_task(name, task_module)
    return names


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.run_name is not None and not re.fullmatch(r"[\w.-]+", args.run_name):
        parser.error(f"--run-name must be a plain folder name (letters, digits, '_', '-', '.'), got {args.run_name!r}")
    settings = SuiteSettings(
        policy=args.policy, policy_path=args.policy_path, out=args.out, episodes=args.episodes,
        demo_sets=args.demo_sets, batch_size=args.batch_size, num_demos=args.num_demos, swap=args.swap,
        task_module=args.task_module, policy_args=tuple(args.policy_args), run_name=args.run_name,
        obs_type=args.obs_type, env_args=tuple(args.env_args), resume=args.resume, success=args.success, **seeds(args),
    )
    try:
        runs = run_suite(settings, resolve_tasks(args.tasks, args.task_module),
                         report=lambda line: print(line, flush=True))
    except (SuiteError, ValueError, RuntimeError, FileExistsError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    results = collect_results([f"{settings.name}={run}" for run in runs], None, DEFAULT_ENV_TYPE)
    json_path, png_path = write_table(results, args.out / f"success_table_{settings.name}",
                                      title=f"bullet_tabletop: {settings.name}, success per task")
    print(format_table(results))
    print(f"\nwrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
