"""The command line of the suite protocol (``evaluation.suite``), shared by ``lerobot-ip-eval-suite``
(``bullet_tabletop``) and ``lerobot-ip-eval-metaworld`` (LeRobot's MetaWorld env).

Both commands take the same arguments (``add_suite_arguments``: the policy and its checkpoint, the tasks, episodes,
demonstration sets, the seed split and its overrides, the context swap, the run's name, ``--resume``, policy and env
config overrides) and each env adds its own (``SuiteCommand``: its policies, default tasks, demonstration sets and
output folder, its arguments, the settings they set and how its task names resolve; ``BULLET_TABLETOP``,
``METAWORLD``). ``run_command`` turns the parsed arguments into :class:`~.suite.SuiteSettings`, runs the suite and
prints its success table, or a one-line error with exit status 2. Each command is one parse and one call::

    parser = build_parser(prog, description, METAWORLD)
    return run_command(parser.prog, METAWORLD, parser.parse_args(argv))
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..sim.env import OBS_TYPES
from ..sim.hand_demonstrator import DEMONSTRATORS
from ..sim.task_api import get_task, task_names
from . import metaworld_suite
from .suite import ENV_TYPE, POLICIES, SEED_SPLITS, SUCCESS_CRITERIA, SuiteError, SuiteSettings, run_and_tabulate


@dataclass(frozen=True)
class SuiteCommand:
    """What one env's suite command adds to the shared arguments: its ``policies`` (``--policy``'s choices), the
    defaults of ``--tasks`` (with its help), ``--demo-sets`` and ``--out``, its own arguments (``add_arguments``),
    the :class:`~.suite.SuiteSettings` fields they set (``settings(args)``) and its task names
    (``resolve_tasks(args)``: checked, ``ValueError`` for an unknown one)."""

    env_type: str
    policies: tuple[str, ...]
    tasks: str
    tasks_help: str
    demo_sets: int
    out: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    settings: Callable[[argparse.Namespace], dict]
    resolve_tasks: Callable[[argparse.Namespace], list[str]]


def build_parser(prog: str, description: str, command: SuiteCommand) -> argparse.ArgumentParser:
    """The parser of ``command``: the shared arguments (``add_suite_arguments``), then the env's own."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    add_suite_arguments(parser, command.policies, command.tasks, command.tasks_help, command.demo_sets, command.out)
    command.add_arguments(parser)
    return parser


def run_command(prog: str, command: SuiteCommand, args: argparse.Namespace) -> int:
    """Run the suite of the parsed ``args`` (their settings, ``suite_settings``, and ``command``'s tasks) and print
    its table; 2 with a one-line error when the settings, the tasks or a ``lerobot-eval`` call fail."""
    try:
        settings = suite_settings(args, command)
        tasks = command.resolve_tasks(args)
        print(run_and_tabulate(settings, tasks, report=lambda line: print(line, flush=True)))
    except (SuiteError, ValueError, RuntimeError, FileExistsError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    return 0


def suite_settings(args: argparse.Namespace, command: SuiteCommand) -> SuiteSettings:
    """The :class:`~.suite.SuiteSettings` of parsed ``build_parser(…, command)`` arguments."""
    return SuiteSettings(
        policy=args.policy, policy_path=args.policy_path, out=args.out, episodes=args.episodes,
        demo_sets=args.demo_sets, batch_size=args.batch_size, num_demos=args.num_demos, swap=args.swap,
        policy_args=tuple(args.policy_args), run_name=args.run_name, resume=args.resume, env_args=tuple(args.env_args),
        env_type=command.env_type, **seeds(args), **command.settings(args),
    )


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
                             "something else (another group), relabelled; with --policy-arg context=language it is "
                             "told that task's name instead")
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


def parse_policy_arg(text: str, prefix: str = "policy") -> str:
    """``KEY=VALUE`` → ``--policy.KEY=VALUE`` (a policy config field overridden for the evaluation)."""
    key, separator, value = text.partition("=")
    if not separator or not key or not value or not key.replace("_", "").replace(".", "").isalnum():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with a {prefix} config field as KEY, got {text!r}")
    return f"--{prefix}.{key}={value}"


def parse_env_arg(text: str) -> str:
    """``KEY=VALUE`` → ``--env.KEY=VALUE`` (an env config field set for the evaluation)."""
    return parse_policy_arg(text, prefix="env")


def run_name(text: str) -> str:
    """A plain folder name (letters, digits, '_', '-', '.')."""
    if not re.fullmatch(r"[\w.-]+", text):
        raise argparse.ArgumentTypeError(f"must be a plain folder name (letters, digits, '_', '-', '.'), got {text!r}")
    return text


def add_bullet_arguments(parser: argparse.ArgumentParser) -> None:
    """``bullet_tabletop``'s own arguments: user tasks, the observation path and the success criterion."""
    parser.add_argument("--task-module", help="module that registers user tasks")
    parser.add_argument("--obs-type", choices=OBS_TYPES, default="pointcloud",
                        help="segmented clouds from the simulator, or raw depth through the perception pipeline")
    parser.add_argument("--success", choices=SUCCESS_CRITERIA, default="held",
                        help="held: the goal state must hold for the task's hold time (default); instant: the first "
                             "step in the goal state counts (the earlier criterion)")
    parser.add_argument("--demonstrator", choices=DEMONSTRATORS, default="gripper",
                        help="who records the demonstration sets: the scripted robot gripper (default), or a simulated "
                             "person's hand, converted from its landmarks (sim.hand_demonstrator)")


def resolve_bullet_tasks(text: str, task_module: str | None) -> list[str]:
    """``all`` (the registered tasks, after importing ``task_module``) or the comma-separated names, each checked."""
    if text == "all":
        if task_module:
            get_task(task_names()[0], task_module)  # imports the module, registering its tasks
        return task_names()
    names = [name.strip() for name in text.split(",") if name.strip()]
    for name in names:
        get_task(name, task_module)
    return names


def add_metaworld_arguments(parser: argparse.ArgumentParser) -> None:
    """MetaWorld's own arguments: the step limit and how often the cloud is rendered (``evaluation.metaworld_suite``)."""
    parser.add_argument("--episode-length", type=int, default=metaworld_suite.DEFAULT_EPISODE_LENGTH,
                        help="step limit per episode (MetaWorld's: 500)")
    parser.add_argument("--pointcloud-every", type=int, default=metaworld_suite.DEFAULT_POINTCLOUD_EVERY,
                        help="render clouds every this many steps and after gripper changes (8: what instant_policy reads)")


def resolve_metaworld_tasks(text: str) -> list[str]:
    """MetaWorld task names and groups (``mt10``, ``ml45_test`` …), each checked; imports neither MetaWorld nor
    MuJoCo."""
    from ..sim.metaworld.configuration_metaworld import resolve_tasks

    return resolve_tasks(text)


BULLET_TABLETOP = SuiteCommand(
    env_type=ENV_TYPE, policies=POLICIES, tasks="all", tasks_help="comma-separated task names, or 'all'",
    demo_sets=3, out="outputs/eval_suite", add_arguments=add_bullet_arguments,
    settings=lambda args: {"task_module": args.task_module, "obs_type": args.obs_type, "success": args.success,
                           "demonstrator": args.demonstrator},
    resolve_tasks=lambda args: resolve_bullet_tasks(args.tasks, args.task_module),
)
METAWORLD = SuiteCommand(
    env_type=metaworld_suite.ENV_TYPE, policies=metaworld_suite.POLICIES, tasks="mt10",
    tasks_help="comma-separated task names or groups: mt10, mt50, ml45_train, ml45_test, easy … very_hard",
    demo_sets=1, out="outputs/eval_metaworld", add_arguments=add_metaworld_arguments,
    settings=lambda args: {"episode_length": args.episode_length, "pointcloud_every": args.pointcloud_every},
    resolve_tasks=lambda args: resolve_metaworld_tasks(args.tasks),
)
