"""The suite protocol of ``evaluation.suite`` on MetaWorld (``lerobot-ip-eval-metaworld``, ``make eval-metaworld``).

For every task (default: MT10) and every demonstration set ``s = 0 … demo_sets − 1``:

* ``num_demos`` demonstrations of MetaWorld's scripted expert are recorded on seeds from ``demo_seed +
  DEMO_SET_STRIDE · s`` (``sim.metaworld.recording``; each set its own seeds, disjoint from the other sets' and from
  every evaluation seed), kept between runs, for the policies that read demonstrations;
* LeRobot's own ``lerobot-eval`` runs the policy in ``--env.type=metaworld_pointcloud`` for ``episodes`` episodes on
  seeds ``eval_seed + episodes · s …``, so every policy meets the same scenes with the same demonstrations;
* with ``swap``, the context-swap control: the policy reads the demonstrations of a task that asks for something
  else (``evaluation.suite.swap_sources`` over ``swap_group``: MT10's tasks that move the hand or an object to a
  place, that open, and that close or press; a task outside MT10 is its own group), recorded by that task's
  expert on the same seeds and labelled with the task evaluated, so a policy that reads its demonstrations loses
  what it read and one that acts from a prior does not.

Seeds: the ``dev`` and ``test`` splits of ``evaluation.suite.SEED_SPLITS``.

Clouds are rendered every ``pointcloud_every`` steps and after gripper changes (8: the steps ``instant_policy`` reads;
``sim.metaworld.env``). Outputs under ``out``: ``demos/<task>-n<N>-s<seed>[-from-<source>]``,
``runs/<run name>/<task>/set-<s>`` (each ``lerobot-eval`` output directory, with its videos and the settings that
decided it, ``suite_cell.json``, which ``resume`` checks as ``evaluation.suite`` does); ``evaluation.success_table``
pools the sets per task.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..sim.metaworld.configuration_metaworld import MT10_TASKS
from .suite import (
    DEMO_SET_STRIDE,
    SuiteError,
    cell_dir,
    check_seeds,
    demo_root,
    run_cells,
    run_lerobot_eval,
    write_cell_record,
)

POLICIES = ("instant_policy", "demo_replay", "do_nothing", "metaworld_expert")
DEMONSTRATION_POLICIES = ("instant_policy", "demo_replay")
ENV_TYPE = "metaworld_pointcloud"
SWAP_GROUPS = {
    "reach or move to a place": ("reach-v3", "push-v3", "pick-place-v3", "peg-insert-side-v3"),
    "open": ("door-open-v3", "drawer-open-v3", "window-open-v3"),
    "close or press": ("drawer-close-v3", "window-close-v3", "button-press-topdown-v3"),
}


def swap_group(task: str) -> str:
    """The MT10 group of ``task`` for the swap control (module docstring); a task outside MT10 is its own group."""
    return next((group for group, tasks in SWAP_GROUPS.items() if task in tasks), task)


@dataclass(frozen=True)
class MetaworldSuiteSettings:
    """What one evaluation of a policy on MetaWorld tasks records, runs and where it writes (module docstring).
    ``policy_args``: ``--policy.KEY=VALUE`` added to every ``lerobot-eval`` call; ``swap``: the context-swap control;
    ``run_name``: the folder under ``out/runs`` (default: the policy, with ``-swap``); ``resume``: keep the cells
    that finished under the same settings instead of evaluating them again."""

    policy: str = "demo_replay"
    policy_path: str | None = None
    tasks: tuple[str, ...] = MT10_TASKS
    out: Path = Path("outputs/eval_metaworld")
    episodes: int = 10
    demo_sets: int = 1
    batch_size: int = 2
    num_demos: int = 2
    demo_seed: int = 0
    eval_seed: int = 1000
    episode_length: int = 200
    pointcloud_every: int = 8
    policy_args: tuple[str, ...] = ()
    swap: bool = False
    run_name: str | None = None
    resume: bool = False
    split: str = "dev"

    def validate(self) -> None:
        if self.policy not in POLICIES:
            raise SuiteError(f"policy must be one of {list(POLICIES)}, got {self.policy!r}")
        if min(self.episodes, self.demo_sets, self.batch_size, self.num_demos, self.pointcloud_every) <= 0:
            raise SuiteError("episodes, demo_sets, batch_size, num_demos and pointcloud_every must be positive")
        if self.policy == "instant_policy" and not self.policy_path:
            raise SuiteError("instant_policy needs a policy_path (a pretrained_model directory)")
        if self.swap and self.policy not in DEMONSTRATION_POLICIES:
            raise SuiteError(f"the context swap needs a policy that reads demonstrations, not {self.policy!r}")
        if self.swap and len(self.tasks) < 2:
            raise SuiteError("the context swap needs at least two tasks")
        check_seeds(self.num_demos, self.demo_seed, self.eval_seed, self.episodes, self.demo_sets)

    @property
    def name(self) -> str:
        """The run's name: ``run_name``, else the policy, with ``-swap`` for the context-swap control."""
        return (self.run_name or self.policy) + ("-swap" if self.swap and not self.run_name else "")

    @property
    def runs_dir(self) -> Path:
        return self.out / "runs" / self.name

    def demo_seed_of(self, demo_set: int) -> int:
        return self.demo_seed + DEMO_SET_STRIDE * demo_set

    def eval_seed_of(self, demo_set: int) -> int:
        return self.eval_seed + self.episodes * demo_set

    def demos_of(self, task: str, demo_set: int, source: str | None) -> Path | None:
        """The expert demonstrations the policy reads in this cell, ``None`` for a policy that reads none."""
        if self.policy not in DEMONSTRATION_POLICIES:
            return None
        return demo_root(self.out, task, self.num_demos, self.demo_seed_of(demo_set), source=source)


def lerobot_eval_command(settings: MetaworldSuiteSettings, task: str, demos: Path, eval_seed: int,
                         output_dir: Path) -> list[str]:
    """The ``lerobot-eval`` command line for one task and demonstration set."""
    policy = f"--policy.path={settings.policy_path}" if settings.policy_path else f"--policy.type={settings.policy}"
    command = [
        str(Path(sys.executable).with_name("lerobot-eval")), f"--env.type={ENV_TYPE}", f"--env.task={task}",
        f"--env.episode_length={settings.episode_length}", f"--env.pointcloud_every={settings.pointcloud_every}",
        policy, f"--eval.n_episodes={settings.episodes}", f"--eval.batch_size={min(settings.batch_size, settings.episodes)}",
        f"--seed={eval_seed}", f"--output_dir={output_dir}", "--policy.device=cpu",
    ]
    if settings.policy in DEMONSTRATION_POLICIES:
        command += [f"--policy.demo_repo_id=local/{task}", f"--policy.demo_root={demos}",
                    f"--policy.num_demos={settings.num_demos}"]
    return command + list(settings.policy_args)


def run_task(settings: MetaworldSuiteSettings, task: str, demo_set: int = 0, source: str | None = None) -> Path:
    """Evaluate ``task`` with demonstration set ``demo_set`` (recorded on first use if the policy reads them;
    ``source``: the swap control's other task, whose expert records them labelled ``task``); returns the
    ``lerobot-eval`` output directory."""
    from ..sim.metaworld.recording import record_expert_demos

    seed = settings.demo_seed_of(demo_set)
    demos = settings.demos_of(task, demo_set, source)
    if demos is not None and not (demos / "meta" / "info.json").is_file():
        record_expert_demos(source or task, settings.num_demos, demos, f"local/{task}", seed, overwrite=True,
                            label=task, episode_length=settings.episode_length)
    output_dir = cell_dir(settings.runs_dir, task, demo_set)
    command = lerobot_eval_command(settings, task, demos, settings.eval_seed_of(demo_set), output_dir)
    run_lerobot_eval(command, settings.runs_dir, task, demo_set)
    write_cell_record(settings, task, demo_set, source)
    return output_dir


def run_suite(settings: MetaworldSuiteSettings, report: Callable[[str], None] = print) -> list[Path]:
    """Every task × demonstration set (module docstring); returns the ``lerobot-eval`` output directories. With
    ``settings.resume`` the finished cells are kept (``evaluation.suite.cells_to_keep`` checks them all before
    anything runs)."""
    settings.validate()
    return run_cells(settings, list(settings.tasks), run_task, report, swap_group)
