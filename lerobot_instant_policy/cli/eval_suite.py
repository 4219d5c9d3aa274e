"""``lerobot-ip-eval-suite``: record demonstrations and run ``lerobot-eval`` on ``bullet_tabletop`` tasks.

For every task: record ``--num-demos`` scripted demonstrations (seeds from ``--demo-seed``, kept between runs),
run LeRobot's own ``lerobot-eval`` with the chosen policy reading them (episode seeds from ``--eval-seed``, so
evaluation scenes differ from the demonstrations), then print the per-task success table and save it as
``OUT/success_table.{json,png}``. ``lerobot-ip-demo`` (``make demo``) is the one-task version.

  lerobot-ip-eval-suite --policy demo_replay --episodes 10 --out outputs/eval_suite
  lerobot-ip-eval-suite --policy instant_policy --policy-path CKPT/pretrained_model --tasks open_drawer,push_button
  lerobot-ip-eval-suite --policy do_nothing --episodes 10 --out outputs/eval_suite   (no demonstrations recorded)
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

from .eval_table import collect_results, format_table, results_json, save_bar_chart
from .record_demos import record

POLICIES = ("demo_replay", "instant_policy", "do_nothing")
DEMONSTRATION_POLICIES = ("demo_replay", "instant_policy")  # the policies that read recorded demonstrations


@dataclass(frozen=True)
class SuiteSettings:
    """What one evaluation of a policy on ``bullet_tabletop`` tasks records, runs and where it writes."""

    policy: str = "demo_replay"
    policy_path: str | None = None
    out: Path = Path("outputs/eval_suite")
    episodes: int = 10
    batch_size: int = 2
    num_demos: int = 2
    demo_seed: int = 0
    eval_seed: int = 1000
    task_module: str | None = None
    policy_args: tuple[str, ...] = ()
    run_name: str | None = None

    @property
    def runs_dir(self) -> Path:
        """``OUT/runs/<run_name or policy>``: one lerobot-eval output dir per task below it."""
        return self.out / "runs" / (self.run_name or self.policy)


def parse_policy_arg(text: str) -> str:
    """``KEY=VALUE`` → ``--policy.KEY=VALUE`` (a policy config field overridden for the evaluation)."""
    key, separator, value = text.partition("=")
    if not separator or not key or not value or not key.replace("_", "").replace(".", "").isalnum():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with a policy config field as KEY, got {text!r}")
    return f"--policy.{key}={value}"


def demo_root(out: Path, task: str, num_demos: int, demo_seed: int) -> Path:
    return out / "demos" / f"{task}-n{num_demos}-s{demo_seed}"


def lerobot_eval_command(
    task: str,
    policy: str,
    policy_path: str | None,
    demos: Path,
    num_demos: int,
    episodes: int,
    batch_size: int,
    eval_seed: int,
    output_dir: Path,
    task_module: str | None = None,
    policy_args: tuple[str, ...] = (),
) -> list[str]:
    """The ``lerobot-eval`` command line for one task."""
    command = [
        str(Path(sys.executable).with_name("lerobot-eval")),
        "--env.type=bullet_tabletop",
        f"--env.task={task}",
        f"--eval.n_episodes={episodes}",
        f"--eval.batch_size={batch_size}",
        f"--seed={eval_seed}",
        f"--output_dir={output_dir}",
        "--policy.device=cpu",
    ]
    if policy in DEMONSTRATION_POLICIES:
        command += [f"--policy.demo_repo_id=local/{task}", f"--policy.demo_root={demos}", f"--policy.num_demos={num_demos}"]
    command.insert(3, f"--policy.path={policy_path}" if policy_path else f"--policy.type={policy}")
    if task_module:
        command.append(f"--env.task_module={task_module}")
    return command + list(policy_args)


def run_task(settings: SuiteSettings, task: str) -> Path:
    """Record (or reuse) the demonstrations of ``task`` if the policy reads them, and evaluate; returns the
    lerobot-eval output dir."""
    demos = demo_root(settings.out, task, settings.num_demos, settings.demo_seed)
    if settings.policy in DEMONSTRATION_POLICIES and not (demos / "meta" / "info.json").is_file():
        record(
            task,
            settings.num_demos,
            demos,
            f"local/{task}",
            settings.demo_seed,
            overwrite=True,
            task_module=settings.task_module,
        )
    output_dir = settings.runs_dir / task
    if output_dir.exists():
        shutil.rmtree(output_dir)
    command = lerobot_eval_command(
        task,
        settings.policy,
        settings.policy_path,
        demos,
        settings.num_demos,
        settings.episodes,
        settings.batch_size,
        settings.eval_seed,
        output_dir,
        settings.task_module,
        settings.policy_args,
    )
    started = time.perf_counter()
    completed = subprocess.run(command, capture_output=True, text=True)
    if completed.returncode != 0:
        log = settings.runs_dir / f"{task}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(completed.stdout + completed.stderr)
        tail = "\n".join((completed.stdout + completed.stderr).strip().splitlines()[-15:])
        raise RuntimeError(f"lerobot-eval failed on {task} (exit {completed.returncode}; full log {log}):\n{tail}")
    print(f"{task}: evaluated in {time.perf_counter() - started:.0f} s -> {output_dir}", flush=True)
    return output_dir


def build_parser(prog: str = "lerobot-ip-eval-suite") -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", choices=POLICIES, default="demo_replay")
    parser.add_argument("--policy-path", help="a pretrained_model directory (instant_policy checkpoints)")
    parser.add_argument("--tasks", default="all", help="comma-separated task names, or 'all'")
    parser.add_argument("--task-module", help="module that registers user tasks")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--num-demos", type=int, default=2)
    parser.add_argument("--demo-seed", type=int, default=0)
    parser.add_argument("--eval-seed", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=Path("outputs/eval_suite"))
    parser.add_argument(
        "--policy-arg",
        dest="policy_args",
        type=parse_policy_arg,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a policy config field, e.g. inference_steps=8 (repeatable; passed as --policy.KEY=VALUE)",
    )
    parser.add_argument("--run-name", help="name of this run's folder under OUT/runs and of its table (default: the policy)")
    return parser


def resolve_tasks(text: str, task_module: str | None) -> list[str]:
    from ..sim.task_api import get_task, task_names

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
    if min(args.episodes, args.batch_size, args.num_demos) <= 0:
        parser.error("--episodes, --batch-size and --num-demos must be positive")
    if args.policy == "instant_policy" and not args.policy_path:
        parser.error("--policy instant_policy needs --policy-path (a pretrained_model directory)")
    if args.run_name is not None and not re.fullmatch(r"[\w.-]+", args.run_name):
        parser.error(f"--run-name must be a plain folder name (letters, digits, '_', '-', '.'), got {args.run_name!r}")
    try:
        tasks = resolve_tasks(args.tasks, args.task_module)
        args.policy_args = tuple(args.policy_args)
        settings = SuiteSettings(**{field.name: getattr(args, field.name) for field in fields(SuiteSettings)})
        runs = [run_task(settings, task) for task in tasks]
    except (ValueError, RuntimeError, FileExistsError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    name = settings.run_name or settings.policy
    results = collect_results([f"{name}={run}" for run in runs], None, "bullet_tabletop")
    table_path = args.out / f"success_table_{name}"
    table_path.with_suffix(".json").write_text(json.dumps(results_json(results), indent=2) + "\n")
    save_bar_chart(results, table_path.with_suffix(".png"), title=f"bullet_tabletop: {name}, success per task")
    print(format_table(results))
    print(f"\nwrote {table_path.with_suffix('.json')} and {table_path.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
