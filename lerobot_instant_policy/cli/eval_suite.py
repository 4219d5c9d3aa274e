"""``lerobot-ip-eval-suite``: record demonstrations and run ``lerobot-eval`` on ``bullet_tabletop`` tasks.

For every task: record ``--num-demos`` scripted demonstrations (seeds from ``--demo-seed``, kept between runs),
run LeRobot's own ``lerobot-eval`` with the chosen policy reading them (episode seeds from ``--eval-seed``, so
evaluation scenes differ from the demonstrations), then print the per-task success table and save it as
``OUT/success_table.{json,png}``. ``lerobot-ip-demo`` (``make demo``) is the one-task version.

  lerobot-ip-eval-suite --policy demo_replay --episodes 10 --out outputs/eval_suite
  lerobot-ip-eval-suite --policy instant_policy --policy-path CKPT/pretrained_model --tasks open_drawer,push_button
  lerobot-ip-eval-suite --policy do_nothing --episodes 10 --out outputs/eval_suite   (no demonstrations recorded)
  lerobot-ip-eval-suite --policy demo_replay --obs-type rgbd --env-arg depth_noise_std=0.002 --run-name noisy

``--obs-type rgbd`` runs the real-robot path: demonstrations are recorded as raw depth + joint states and
converted with ``lerobot-ip-convert``'s pipeline, and the env hands out depth only (``--env.obs_type=rgbd``), which
its env preprocessor turns into segmented clouds. ``--env-arg KEY=VALUE`` sets ``--env.KEY=VALUE`` (sensor noise,
calibration error) for the evaluation only; demonstrations are always recorded clean.
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

from ..sim.configuration_bullet_tabletop import OBS_TYPES
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
    obs_type: str = "pointcloud"
    env_args: tuple[str, ...] = ()

    @property
    def runs_dir(self) -> Path:
        """``OUT/runs/<run_name or policy>``: one lerobot-eval output dir per task below it."""
        return self.out / "runs" / (self.run_name or self.policy)


def parse_policy_arg(text: str, prefix: str = "policy") -> str:
    """``KEY=VALUE`` → ``--policy.KEY=VALUE`` (a policy config field overridden for the evaluation)."""
    key, separator, value = text.partition("=")
    if not separator or not key or not value or not key.replace("_", "").replace(".", "").isalnum():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE with a {prefix} config field as KEY, got {text!r}")
    return f"--{prefix}.{key}={value}"


def parse_env_arg(text: str) -> str:
    """``KEY=VALUE`` → ``--env.KEY=VALUE`` (an env config field set for the evaluation)."""
    return parse_policy_arg(text, prefix="env")


def demo_root(out: Path, task: str, num_demos: int, demo_seed: int, obs_type: str = "pointcloud") -> Path:
    """Where the demonstrations read by the policy live; for ``rgbd`` the converted dataset (the raw recording
    sits beside it, ``...-rgbd-raw``)."""
    suffix = "" if obs_type == "pointcloud" else f"-{obs_type}"
    return out / "demos" / f"{task}-n{num_demos}-s{demo_seed}{suffix}"


def record_rgbd_demos(settings: SuiteSettings, task: str, demos: Path) -> None:
    """Record raw depth demonstrations of ``task`` and convert them (robot removed by its joint state) to ``demos``."""
    from ..sim.robot import JOINT_NAMES, low_poly_panda_urdf
    from .convert import ConvertSettings, convert
    from .record_demos import JOINT_POSITIONS_KEY

    raw = demos.with_name(demos.name + "-raw")
    record(task, settings.num_demos, raw, f"local/{task}-raw", settings.demo_seed, overwrite=True,
           task_module=settings.task_module, obs_type="rgbd")
    convert(
        ConvertSettings(
            input_root=raw,
            input_repo_id=f"local/{task}-raw",
            out=demos,
            repo_id=f"local/{task}",
            action_source="dataset",
            urdf=low_poly_panda_urdf(),
            joint_key=JOINT_POSITIONS_KEY,
            joint_names=list(JOINT_NAMES),
            overwrite=True,
        )
    )


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
    env_args: tuple[str, ...] = (),
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
    return command + list(policy_args) + list(env_args)


def run_task(settings: SuiteSettings, task: str) -> Path:
    """Record (or reuse) the demonstrations of ``task`` if the policy reads them, and evaluate; returns the
    lerobot-eval output dir."""
    demos = demo_root(settings.out, task, settings.num_demos, settings.demo_seed, settings.obs_type)
    needs_demos = settings.policy in DEMONSTRATION_POLICIES and not (demos / "meta" / "info.json").is_file()
    if needs_demos and settings.obs_type == "rgbd":
        record_rgbd_demos(settings, task, demos)
    elif needs_demos:
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
        settings.env_args + ((f"--env.obs_type={settings.obs_type}",) if settings.obs_type != "pointcloud" else ()),
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
    parser.add_argument(
        "--obs-type", choices=OBS_TYPES, default="pointcloud",
        help="segmented clouds from the simulator, or raw depth through the perception pipeline",
    )
    parser.add_argument(
        "--env-arg",
        dest="env_args",
        type=parse_env_arg,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set an env config field for the evaluation, e.g. depth_noise_std=0.002 (repeatable; --env.KEY=VALUE)",
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
        args.env_args = tuple(args.env_args)
        settings = SuiteSettings(**{field.name: getattr(args, field.name) for field in fields(SuiteSettings)})
        runs = [run_task(settings, task) for task in tasks]
    except (ValueError, RuntimeError, FileExistsError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    name = settings.run_name or settings.policy
    results = collect_results([f"{name}={run}" for run in runs], None, "bullet_tabletop")
    json_path, png_path = args.out / f"success_table_{name}.json", args.out / f"success_table_{name}.png"
    json_path.write_text(json.dumps(results_json(results), indent=2) + "\n")
    save_bar_chart(results, png_path, title=f"bullet_tabletop: {name}, success per task")
    print(format_table(results))
    print(f"\nwrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
