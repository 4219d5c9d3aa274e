"""``lerobot-ip-eval-suite``: record demonstration sets and run ``lerobot-eval`` on ``bullet_tabletop`` tasks, then
print the success table with cluster (over tasks) and per-episode 95% intervals (``evaluation.suite``,
``evaluation.success_table``).

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
from collections.abc import Callable
from pathlib import Path

from ..evaluation.suite import POLICIES, SEED_SPLITS, SUCCESS_CRITERIA, SuiteError, SuiteSettings, run_and_tabulate
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


def add_suite_arguments(parser: argparse.ArgumentParser, policies: tuple[str, ...], tasks: str, tasks_help: str,
                        demo_sets: int, out: str) -> None:
    """The arguments both suites' commands take (``evaluation.suite.SuiteSettings``), with their defaults."""
    parser.add_argument("--policy", choices=policies, default="demo_replay")
    parser.add_argument("--policy-path", help="a pretrained_model directory (instant_policy checkpoints)")
    parser.add_argument("--tasks", default=tasks, help=tasks_help)
    parser.add_argument("--episodes", type=int, default=10, help="evaluation episodes per task and demonstration set")
    parser.add_argument("--demo-sets", type=int, default=demo_sets,
                        help=f"disjoint demonstration sets per task, each recorded on its own seeds (default {demo_sets})")
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--num-demos", type=int, default=2)
    add_seed_arguments(parser)
    parser.add_argument("--swap", action="store_true",
                        help="the context-swap control: each task reads the demonstrations of a task that asks for "
                             "something else (another group), relabelled")
    parser.add_argument("--out", type=Path, default=Path(out))
    parser.add_argument("--policy-arg", dest="policy_args", type=parse_policy_arg, action="append", default=[],
                        metavar="KEY=VALUE",
                        help="override a policy config field, e.g. inference_steps=8 (repeatable; --policy.KEY=VALUE)")
    parser.add_argument("--run-name", type=run_name, help="name of this run's folder under OUT/runs and of its table "
                                                          "(default: the policy, with -swap for --swap)")
    parser.add_argument("--resume", action="store_true",
                        help="keep the cells of OUT/runs/<name> already evaluated with the same settings and evaluate "
                             "the rest (refused if a finished cell's settings differ)")
    parser.add_argument("--env-arg", dest="env_args", type=parse_env_arg, action="append", default=[],
                        metavar="KEY=VALUE", help="set an env config field for the evaluation (--env.KEY=VALUE), e.g. "
                        "render_size=64: the size of the videos' frames, which changes no observation (repeatable)")


def run_name(text: str) -> str:
    """A plain folder name (letters, digits, '_', '-', '.')."""
    if not re.fullmatch(r"[\w.-]+", text):
        raise argparse.ArgumentTypeError(f"must be a plain folder name (letters, digits, '_', '-', '.'), got {text!r}")
    return text


def suite_settings(args: argparse.Namespace, **env_settings) -> SuiteSettings:
    """The :class:`SuiteSettings` of parsed :func:`add_suite_arguments`, with the env's own ``env_settings``."""
    return SuiteSettings(
        policy=args.policy, policy_path=args.policy_path, out=args.out, episodes=args.episodes,
        demo_sets=args.demo_sets, batch_size=args.batch_size, num_demos=args.num_demos, swap=args.swap,
        policy_args=tuple(args.policy_args), run_name=args.run_name, resume=args.resume, env_args=tuple(args.env_args),
        **seeds(args), **env_settings,
    )


def run(prog: str, plan: Callable[[], tuple[SuiteSettings, list[str]]]) -> int:
    """Run the suite ``plan()`` gives (settings and tasks) and print its table; 2 with a one-line error when the
    settings, the tasks or a ``lerobot-eval`` call fail."""
    try:
        settings, tasks = plan()
        print(run_and_tabulate(settings, tasks, report=lambda line: print(line, flush=True)))
    except (SuiteError, ValueError, RuntimeError, FileExistsError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-eval-suite", description=__doc__.split("\n\n")[0])
    add_suite_arguments(parser, POLICIES, "all", "comma-separated task names, or 'all'", 3, "outputs/eval_suite")
    parser.add_argument("--task-module", help="module that registers user tasks")
    parser.add_argument("--obs-type", choices=OBS_TYPES, default="pointcloud",
                        help="segmented clouds from the simulator, or raw depth through the perception pipeline")
    parser.add_argument("--success", choices=SUCCESS_CRITERIA, default="held",
                        help="held: the goal state must hold for the task's hold time (default); instant: the first "
                             "step in the goal state counts (the earlier criterion)")
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
    return run(parser.prog, lambda: (
        suite_settings(args, task_module=args.task_module, obs_type=args.obs_type, success=args.success),
        resolve_tasks(args.tasks, args.task_module),
    ))


if __name__ == "__main__":
    sys.exit(main())
