"""The suite protocol: demonstration sets, evaluation seeds, the context-swap control, and ``lerobot-eval`` per task,
in ``bullet_tabletop`` (``lerobot-ip-eval-suite``, ``make results-suite``, ``make demo``) and in LeRobot's MetaWorld
env (``lerobot-ip-eval-metaworld``, ``make eval-metaworld``; what differs there is in ``metaworld_suite``).

Protocol. For every task and every demonstration set ``s = 0 … demo_sets − 1``:

* ``num_demos`` scripted demonstrations are recorded on seeds from ``demo_seed + DEMO_SET_STRIDE · s`` (each set its
  own seeds, disjoint from the other sets' and from every evaluation seed), kept between runs;
* LeRobot's own ``lerobot-eval`` runs the policy reading them for ``episodes`` episodes on seeds
  ``eval_seed + episodes · s …`` (``lerobot-eval`` seeds episode ``i`` with ``--seed + i``), so every set meets its
  own scenes and every policy meets the same scenes; it runs with ``evaluation.lerobot_eval_seeds``'s wrapper, which
  keeps the seed of every episode, as lerobot-eval reports it, in ``eval_info.json``;
* with ``swap``, the policy instead reads the demonstrations of another task of the suite, one that asks for
  something else (``swap_sources``: a permutation, every task's demonstrations read by one other task, of another
  task group; the same seeds), relabelled as this task's: the control that tells reading the demonstrations from a
  prior that solves the task alone. With ``--policy.context=language`` the policy reads no demonstrations and is
  told the other task's name instead (``--policy.language_instruction``): the control that tells following the words
  from acting on the scene alone.

Seeds come in two disjoint splits (``SEED_SPLITS``): ``dev`` (demonstrations from seed 0, episodes from 1000), on
which every study, option and checkpoint is chosen, and ``test`` (demonstrations from 50,000, episodes from 60,000),
run once per shipped candidate and reported. ``make demo`` uses neither. ``success``: the env's success criterion
(``held``, the default, or ``instant``; ``sim.env``).

Outputs under ``out``: ``demos/<task>-n<N>-s<seed>[-from-<source>]`` (the recorded sets), ``runs/<run name>/<task>/
set-<s>`` (each ``lerobot-eval`` output directory, with ``suite_cell.json``: the settings that decided its result,
the cell's seeds and demonstration fingerprint, and every condition that changes its outcome resolved for the cell
(``cell_conditions``: the checkpoint's SHA-256, the hold steps, the step limit, …), ``evaluation.manifest``;
``resume`` keeps the finished cells evaluated with the same settings and conditions, the video size aside, and
evaluates the rest); ``evaluation.success_table`` pools the sets per task.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from ..language.task_language import SHIPPED_LANGUAGE_HEAD
from ..sim.env import SUCCESS_CRITERIA
from ..sim.hand_demonstrator import DEMONSTRATORS
from ..sim.recording import record
from ..sim.task_api import get_task
from . import metaworld_suite
from .manifest import CELL_FILE, LANGUAGE_CONTEXT_ARG, cell_identity, checkpoint_fingerprint
from .success_table import collect_results, format_table, task_group, write_table

ENV_TYPE = "bullet_tabletop"
POLICIES = ("demo_replay", "instant_policy", "do_nothing")  # bullet_tabletop's
DEMONSTRATION_POLICIES = ("demo_replay", "instant_policy")  # the policies that read recorded demonstrations
DEMO_SET_STRIDE = 100  # demonstration set s records from seed demo_seed + 100 s: room for failed scripted seeds
SEED_SPLITS = {"dev": (0, 1000), "test": (50_000, 60_000)}  # split: (first demonstration seed, first episode seed)
# settings that decide no cell's result: where and how many (a cell's task and set are its own), and the videos'
# size (rendering changes no observation)
NOT_RESULT_SETTINGS = ("out", "demo_sets", "run_name", "resume", "split", "env_type")
VIDEO_ENV_ARGS = ("--env.render_size=",)
LEROBOT_EVAL = "lerobot_instant_policy.evaluation.lerobot_eval_seeds"  # lerobot-eval, keeping each episode's seed


class SuiteError(ValueError):
    """Bad suite settings, or a ``lerobot-eval`` run that failed."""


@dataclass(frozen=True)
class SuiteEnv:
    """What the protocol does differently in one env: its ``policies``, the settings that apply to it alone
    (``fields``: recorded per cell; other envs' fields must keep their defaults), how it records a demonstration set
    (``record(settings, task, demos, seed, source)``), the swap control's task groups (``group_of``), its flags on
    every ``lerobot-eval`` call (``eval_flags(settings)``), its own checks (``check(settings)``: a message or
    ``None``) and its part of a cell's conditions (``conditions(settings, task, env_values)``: the success criterion,
    hold steps, step limit, video size, observation settings; ``env_values``: the ``--env.KEY=VALUE`` arguments by
    key)."""

    policies: tuple[str, ...]
    fields: tuple[str, ...]
    record: Callable[..., None]
    group_of: Callable[[str], str]
    eval_flags: Callable[..., list[str]]
    check: Callable[..., str | None]
    conditions: Callable[..., dict]


@dataclass(frozen=True)
class SuiteSettings:
    """What one evaluation of a policy records, runs and where it writes (module docstring), in ``env_type``
    (``bullet_tabletop`` or ``metaworld_pointcloud``). ``policy_args``: ``--policy.KEY=VALUE`` added to every
    ``lerobot-eval`` call. ``resume``: keep the cells of ``runs_dir`` that finished under the same settings instead of
    evaluating them again. ``split``: the name of the seed split ``demo_seed`` and ``eval_seed`` come from
    (``custom`` for others).

    ``env_args``: ``--env.KEY=VALUE`` for the evaluation only (demonstrations are always recorded clean).

    ``bullet_tabletop`` only: ``task_module`` (user tasks), ``obs_type`` (``rgbd``: the real-robot path), ``success``
    (``held`` or ``instant``), ``demonstrator`` (``gripper``: the scripted robot; ``hand``: a simulated person's hand,
    its recordings converted from landmarks, ``sim.hand_demonstrator``). ``metaworld_pointcloud`` only:
    ``episode_length`` and ``pointcloud_every`` (``metaworld_suite``)."""

    policy: str = "demo_replay"
    policy_path: str | None = None
    out: Path = Path("outputs/eval_suite")
    episodes: int = 10
    demo_sets: int = 3
    batch_size: int = 2
    num_demos: int = 2
    demo_seed: int = 0
    eval_seed: int = 1000
    swap: bool = False
    task_module: str | None = None
    policy_args: tuple[str, ...] = ()
    run_name: str | None = None
    obs_type: str = "pointcloud"
    env_args: tuple[str, ...] = ()
    resume: bool = False
    success: str = "held"
    split: str = "dev"
    env_type: str = ENV_TYPE
    episode_length: int = metaworld_suite.DEFAULT_EPISODE_LENGTH
    pointcloud_every: int = metaworld_suite.DEFAULT_POINTCLOUD_EVERY
    demonstrator: str = "gripper"

    @property
    def env(self) -> SuiteEnv:
        if self.env_type not in SUITE_ENVS:
            raise SuiteError(f"env_type must be one of {list(SUITE_ENVS)}, got {self.env_type!r}")
        return SUITE_ENVS[self.env_type]

    def validate(self) -> None:
        env = self.env
        if self.policy not in env.policies:
            raise SuiteError(f"policy must be one of {list(env.policies)} in {self.env_type}, got {self.policy!r}")
        defaults = SuiteSettings()
        for other_type, other in SUITE_ENVS.items():
            changed = [name for name in other.fields if name not in env.fields
                       and getattr(self, name) != getattr(defaults, name)]
            if changed:
                raise SuiteError(f"{', '.join(changed)} applies to {other_type} only, not {self.env_type}")
        problem = env.check(self)
        if problem:
            raise SuiteError(problem)
        if min(self.episodes, self.demo_sets, self.batch_size, self.num_demos) <= 0:
            raise SuiteError("episodes, demo_sets, batch_size and num_demos must be positive")
        if self.policy == "instant_policy" and not self.policy_path:
            raise SuiteError("instant_policy needs a policy_path (a pretrained_model directory)")
        if self.swap and not (self.reads_demonstrations or self.says_tasks_in_words):
            raise SuiteError(f"the context swap needs a policy that reads demonstrations or the task in words, not "
                             f"{self.policy!r}")
        check_seeds(self.num_demos, self.demo_seed, self.eval_seed, self.episodes, self.demo_sets)

    @property
    def name(self) -> str:
        """The run's name: ``run_name``, else the policy, with ``-swap`` for the context-swap control."""
        return (self.run_name or self.policy) + ("-swap" if self.swap and not self.run_name else "")

    @property
    def runs_dir(self) -> Path:
        """``OUT/runs/<name>``: one folder per task, one ``lerobot-eval`` output dir per set below it."""
        return self.out / "runs" / self.name

    def demo_seed_of(self, demo_set: int) -> int:
        return self.demo_seed + DEMO_SET_STRIDE * demo_set

    def eval_seed_of(self, demo_set: int) -> int:
        return self.eval_seed + self.episodes * demo_set

    @property
    def reads_demonstrations(self) -> bool:
        """Whether the policy reads recorded demonstrations: ``DEMONSTRATION_POLICIES``, but not ``instant_policy``
        told ``--policy-arg context=language`` (each task said in words)."""
        return self.policy in DEMONSTRATION_POLICIES and LANGUAGE_CONTEXT_ARG not in self.policy_args

    @property
    def says_tasks_in_words(self) -> bool:
        """Whether the policy is ``instant_policy`` told ``--policy-arg context=language``."""
        return self.policy == "instant_policy" and LANGUAGE_CONTEXT_ARG in self.policy_args

    def demos_of(self, task: str, demo_set: int, source: str | None) -> Path | None:
        """The demonstration dataset the policy reads in this cell, ``None`` for a policy that reads none."""
        if not self.reads_demonstrations:
            return None
        return demo_root(self.out, task, self.num_demos, self.demo_seed_of(demo_set), self.obs_type, source,
                         self.demonstrator)


def check_seeds(num_demos: int, demo_seed: int, eval_seed: int, episodes: int, demo_sets: int) -> None:
    """``SuiteError`` unless every set's ``num_demos`` fit its seed span and no demonstration seed (set s from
    ``demo_seed + DEMO_SET_STRIDE · s``) is an evaluation seed (set s from ``eval_seed + episodes · s``)."""
    if num_demos > DEMO_SET_STRIDE // 2:
        raise SuiteError(f"num_demos must be at most {DEMO_SET_STRIDE // 2} (each set's seeds span "
                         f"{DEMO_SET_STRIDE})")
    last_demo_seed = demo_seed + DEMO_SET_STRIDE * demo_sets
    last_eval_seed = eval_seed + episodes * demo_sets
    if demo_seed < last_eval_seed and eval_seed < last_demo_seed:
        raise SuiteError(f"demonstration seeds {demo_seed}…{last_demo_seed - 1} overlap evaluation seeds "
                         f"{eval_seed}…{last_eval_seed - 1}: choose another demo_seed or eval_seed")


def swap_sources(tasks: list[str], group_of: Callable[[str], str]) -> dict[str, str]:
    """Each task's source of demonstrations in the context-swap control, a permutation of ``tasks`` (every task's
    demonstrations read by exactly one other task): the tasks listed group by group (``group_of``; groups in order of
    first appearance, tasks in their order), each reads the task ``shift`` places further on, cyclically, with
    ``shift`` the size of the largest group. No group spans ``shift`` places, so when no group holds more than half
    the tasks every task reads one of another group, one that asks for something else; where the groups are of one
    size, the task at the same place in the next group. When a group holds more than half (one group: all), no
    permutation can give every task another group's; ``shift`` is then half the list, so that every task outside
    that group and as many of its own as there are tasks outside it read another group's, and no task its own."""
    tasks = list(dict.fromkeys(tasks))
    if len(tasks) < 2:
        raise SuiteError("the context swap needs at least two tasks")
    groups: dict[str, list[str]] = {}
    for task in tasks:
        groups.setdefault(group_of(task), []).append(task)
    ordered = [task for group in groups.values() for task in group]
    largest = max(len(group) for group in groups.values())
    shift = largest if 2 * largest <= len(ordered) else len(ordered) // 2
    source = {task: ordered[(index + shift) % len(ordered)] for index, task in enumerate(ordered)}
    return {task: source[task] for task in tasks}


def demo_root(out: Path, task: str, num_demos: int, demo_seed: int, obs_type: str = "pointcloud",
              source: str | None = None, demonstrator: str = "gripper") -> Path:
    """Where the demonstrations of ``task`` read by the policy live (``source``: recorded on that task instead and
    labelled ``task``); for ``rgbd`` the converted dataset (the raw recording sits beside it, ``...-rgbd-raw``); for
    the ``hand`` demonstrator the converted dataset of ``...-hand`` (its recordings beside it, ``...-hand-recordings``),
    whatever the evaluation's ``obs_type``."""
    if demonstrator == "hand":
        return out / "demos" / (f"{task}-n{num_demos}-s{demo_seed}-hand" + (f"-from-{source}" if source else ""))
    suffix = ("" if obs_type == "pointcloud" else f"-{obs_type}") + (f"-from-{source}" if source else "")
    return out / "demos" / f"{task}-n{num_demos}-s{demo_seed}{suffix}"


def record_demonstrations(settings: SuiteSettings, task: str, demos: Path, seed: int, source: str) -> None:
    """Record ``settings.num_demos`` demonstrations of ``source`` labelled ``task`` into ``demos``; for ``rgbd`` as
    raw depth, converted (robot removed by its joint state) beside it; by the ``hand`` demonstrator as hand
    recordings, converted from their landmarks (``sim.hand_demonstrator``)."""
    if settings.demonstrator == "hand":
        from ..sim.hand_demonstrator import record_hand_demonstrations

        record_hand_demonstrations(source, settings.num_demos, demos, f"local/{task}", seed, overwrite=True,
                                   task_module=settings.task_module, label=task)
        return
    if settings.obs_type != "rgbd":
        record(source, settings.num_demos, demos, f"local/{task}", seed, overwrite=True,
               task_module=settings.task_module, label=task)
        return
    from ..perception.convert import ConvertSettings, convert
    from ..sim.recording import JOINT_POSITIONS_KEY
    from ..sim.robot import JOINT_NAMES, low_poly_panda_urdf

    raw = demos.with_name(demos.name + "-raw")
    record(source, settings.num_demos, raw, f"local/{task}-raw", seed, overwrite=True,
           task_module=settings.task_module, obs_type="rgbd", label=task)
    convert(ConvertSettings(
        input_root=raw, input_repo_id=f"local/{task}-raw", out=demos, repo_id=f"local/{task}",
        action_source="dataset", urdf=low_poly_panda_urdf(), joint_key=JOINT_POSITIONS_KEY,
        joint_names=list(JOINT_NAMES), overwrite=True,
    ))


def bullet_eval_flags(settings: SuiteSettings) -> list[str]:
    """The env flags of every ``lerobot-eval`` call in ``bullet_tabletop``."""
    flags = [f"--env.success={settings.success}"]
    if settings.task_module:
        flags.append(f"--env.task_module={settings.task_module}")
    return flags + ([f"--env.obs_type={settings.obs_type}"] if settings.obs_type != "pointcloud" else [])


def bullet_check(settings: SuiteSettings) -> str | None:
    """What is wrong with ``settings`` for ``bullet_tabletop`` (``None`` when nothing is)."""
    if settings.success not in SUCCESS_CRITERIA:
        return f"success must be one of {list(SUCCESS_CRITERIA)}, got {settings.success!r}"
    if settings.demonstrator not in DEMONSTRATORS:
        return f"demonstrator must be one of {list(DEMONSTRATORS)}, got {settings.demonstrator!r}"
    return None


def bullet_conditions(settings: SuiteSettings, task: str, env_values: dict[str, str]) -> dict:
    """``bullet_tabletop``'s part of a cell's conditions: the criterion, the steps the goal state must hold (the
    task's ``success_hold_steps`` when held, else 1), the step limit (``--env.episode_length`` or the task's), the
    video size (``--env.render_size`` or the env config's) and the observation path."""
    from ..sim.configuration_bullet_tabletop import BulletTabletopEnvConfig

    task_class = get_task(task, settings.task_module)
    return {"success": settings.success,
            "hold_steps": task_class.success_hold_steps if settings.success == "held" else 1,
            "episode_length": int(env_values.get("episode_length", task_class.max_episode_steps)),
            "render_size": int(env_values.get("render_size", BulletTabletopEnvConfig.render_size)),
            "obs_type": settings.obs_type, "pointcloud_every": None}


SUITE_ENVS = {
    ENV_TYPE: SuiteEnv(POLICIES, ("task_module", "obs_type", "success", "demonstrator"), record_demonstrations,
                       task_group, bullet_eval_flags, bullet_check, bullet_conditions),
    metaworld_suite.ENV_TYPE: SuiteEnv(metaworld_suite.POLICIES, ("episode_length", "pointcloud_every"),
                                       metaworld_suite.record_demonstrations, metaworld_suite.swap_group,
                                       metaworld_suite.eval_flags, metaworld_suite.check, metaworld_suite.conditions),
}


def lerobot_eval_command(settings: SuiteSettings, task: str, demos: Path | None, eval_seed: int,
                         output_dir: Path, source: str | None = None) -> list[str]:
    """The ``lerobot-eval`` command line for one task and demonstration set (run through ``LEROBOT_EVAL``, which
    keeps each episode's seed in ``eval_info.json``); ``source``: the swap control's other task, whose name a policy
    that reads the task in words is told."""
    command = [
        sys.executable, "-m", LEROBOT_EVAL,
        f"--env.type={settings.env_type}",
        f"--env.task={task}",
        f"--policy.path={settings.policy_path}" if settings.policy_path else f"--policy.type={settings.policy}",
        f"--eval.n_episodes={settings.episodes}",
        f"--eval.batch_size={min(settings.batch_size, settings.episodes)}",
        f"--seed={eval_seed}",
        f"--output_dir={output_dir}",
        "--policy.device=cpu",
        *settings.env.eval_flags(settings),
        *settings.env_args,
    ]
    if settings.reads_demonstrations:
        command += [f"--policy.demo_repo_id=local/{task}", f"--policy.demo_root={demos}",
                    f"--policy.num_demos={settings.num_demos}"]
    if source is not None and settings.says_tasks_in_words:
        command.append(f"--policy.language_instruction={source}")
    return command + list(settings.policy_args)


def run_task(settings: SuiteSettings, task: str, demo_set: int = 0, source: str | None = None) -> Path:
    """Evaluate ``task`` with demonstration set ``demo_set`` (recorded on first use if the policy reads them;
    ``source``: the swap control's other task); returns the ``lerobot-eval`` output directory."""
    seed = settings.demo_seed_of(demo_set)
    demos = settings.demos_of(task, demo_set, source)
    if demos is not None and not (demos / "meta" / "info.json").is_file():
        settings.env.record(settings, task, demos, seed, source or task)
    output_dir = cell_dir(settings.runs_dir, task, demo_set)
    command = lerobot_eval_command(settings, task, demos, settings.eval_seed_of(demo_set), output_dir, source)
    conditions = cell_conditions(settings, task)
    run_lerobot_eval(command, settings.runs_dir, task, demo_set)
    write_cell_record(settings, task, demo_set, source, conditions)
    return output_dir


def arg_values(args: tuple[str, ...], prefix: str) -> dict[str, str]:
    """``--PREFIX.KEY=VALUE`` arguments (``prefix``: ``env`` or ``policy``) as ``{KEY: VALUE}`` (the last of a
    repeated key)."""
    start = f"--{prefix}."
    return dict(arg.removeprefix(start).split("=", 1) for arg in args if arg.startswith(start) and "=" in arg)


def cell_conditions(settings: SuiteSettings, task: str) -> dict:
    """The ``"conditions"`` record of a cell of ``task`` (JSON-ready, ``manifest.CONDITIONS``): the SHA-256 of the
    checkpoint (``None``: the policy loads none) and of the language head the policy says tasks with (``None``: it
    reads demonstrations), the policy options, the env arguments but the video size, and the env's own
    (``SuiteEnv.conditions``)."""
    checkpoint = language_head = None
    if settings.policy_path:
        checkpoint = _fingerprint_of(Path(settings.policy_path))
    if settings.says_tasks_in_words:
        head_path = arg_values(settings.policy_args, "policy").get("language_head_path")
        language_head = _fingerprint_of(Path(head_path).expanduser() if head_path else SHIPPED_LANGUAGE_HEAD)
    return {"checkpoint_sha256": checkpoint, "language_head_sha256": language_head,
            "policy_options": list(settings.policy_args),
            "env_args": [arg for arg in settings.env_args if not arg.startswith(VIDEO_ENV_ARGS)],
            **settings.env.conditions(settings, task, arg_values(settings.env_args, "env"))}


def _fingerprint_of(path: Path) -> str:
    """``manifest.checkpoint_fingerprint`` of a directory the policy loads, or why there is none."""
    return checkpoint_fingerprint(path) if path.is_dir() else f"not a local directory: {path}"


def write_cell_record(settings: SuiteSettings, task: str, demo_set: int, source: str | None,
                      conditions: dict | None) -> None:
    """``suite_cell.json`` of a finished cell: what decided its result (``cell_record``), under ``"cell"`` its
    seeds and demonstration set (``manifest.cell_identity``) and under ``"conditions"`` what it ran under
    (``cell_conditions``, taken before it ran; ``None`` for a cell kept from an earlier run: unknown, not written)."""
    record = cell_record(settings, source)
    if conditions is not None:
        record["conditions"] = conditions
    record["cell"] = cell_identity(task, demo_set, settings.eval_seed_of(demo_set), settings.episodes,
                                   settings.demo_seed_of(demo_set), settings.num_demos,
                                   settings.demos_of(task, demo_set, source), source)
    (cell_dir(settings.runs_dir, task, demo_set) / CELL_FILE).write_text(json.dumps(record, indent=2) + "\n")


def cell_dir(runs_dir: Path, task: str, demo_set: int) -> Path:
    """``runs_dir/<task>/set-<demo_set>``: the ``lerobot-eval`` output directory of one task and demonstration set."""
    return runs_dir / task / f"set-{demo_set}"


def run_lerobot_eval(command: list[str], runs_dir: Path, task: str, demo_set: int) -> Path:
    """Run ``command`` (a ``lerobot-eval`` call writing to ``runs_dir/<task>/set-<demo_set>``, emptied first) and
    return that directory; a ``SuiteError`` with the output's tail when it fails, the whole output kept in
    ``runs_dir/<task>-set-<demo_set>.log``."""
    output_dir = cell_dir(runs_dir, task, demo_set)
    if output_dir.exists():
        shutil.rmtree(output_dir)
    completed = subprocess.run(command, capture_output=True, text=True)
    if completed.returncode != 0:
        log = runs_dir / f"{task}-set-{demo_set}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(completed.stdout + completed.stderr)
        tail = "\n".join((completed.stdout + completed.stderr).strip().splitlines()[-15:])
        raise SuiteError(f"lerobot-eval failed on {task}, set {demo_set} (exit {completed.returncode}; full log "
                         f"{log}):\n{tail}")
    return output_dir


def run_suite(settings: SuiteSettings, tasks: list[str], report: Callable[[str], None] = print) -> list[Path]:
    """``run_task`` for every task × demonstration set (module docstring), ``source`` the swap control's other task
    (``swap_sources`` over the env's groups); returns the ``lerobot-eval`` output directories in order. With
    ``settings.resume`` the finished cells are kept (``cells_to_keep`` checks them all before anything runs)."""
    settings.validate()
    swapped = swap_sources(tasks, settings.env.group_of) if settings.swap else {}
    sources = {task: swapped.get(task) for task in tasks}
    kept = cells_to_keep(settings, sources) if settings.resume else set()
    runs = []
    for task, source in sources.items():
        with_demos = f" with {source}'s demonstrations" if source else ""
        for demo_set in range(settings.demo_sets):
            if (task, demo_set) in kept:
                runs.append(cell_dir(settings.runs_dir, task, demo_set))
                if "cell" not in json.loads((runs[-1] / CELL_FILE).read_text()):  # kept from before cells had one
                    write_cell_record(settings, task, demo_set, source, conditions=None)
                report(f"{task}, set {demo_set}{with_demos}: kept from the earlier run -> {runs[-1]}")
                continue
            started = time.perf_counter()
            runs.append(run_task(settings, task, demo_set, source))
            report(f"{task}, set {demo_set}{with_demos}: evaluated in {time.perf_counter() - started:.0f} s -> "
                   f"{runs[-1]}")
    return runs


def run_and_tabulate(settings: SuiteSettings, tasks: list[str], report: Callable[[str], None] = print) -> str:
    """:func:`run_suite`, then the run's success table (Wilson intervals), written to ``OUT/success_table_<name>
    .{json,png}``; returns the table as text with where it was written."""
    runs = run_suite(settings, tasks, report)
    results = collect_results([f"{settings.name}={run}" for run in runs], None, settings.env_type)
    json_path, png_path = write_table(results, settings.out / f"success_table_{settings.name}",
                                      title=f"{settings.env_type}: {settings.name}, success per task")
    return f"{format_table(results)}\n\nwrote {json_path} and {png_path}"


def cell_record(settings: SuiteSettings, source: str | None) -> dict:
    """What decides a cell's result (JSON-ready): the settings but ``NOT_RESULT_SETTINGS``, other envs' own fields
    and the video size, and the swap's source task."""
    others = {name for env in SUITE_ENVS.values() for name in env.fields} - set(settings.env.fields)
    record = {key: value for key, value in asdict(settings).items()
              if key not in NOT_RESULT_SETTINGS and key not in others}
    record["env_args"] = [arg for arg in settings.env_args if not arg.startswith(VIDEO_ENV_ARGS)]
    record["policy_args"] = list(settings.policy_args)
    record["swap_source"] = source
    if record.get("demonstrator") == "gripper":  # the default: cells recorded before the option read the same
        del record["demonstrator"]
    return record


def cells_to_keep(settings: SuiteSettings, sources: dict[str, str | None]) -> set[tuple[str, int]]:
    """``(task, set)`` of the finished cells (``eval_info.json`` written) of ``settings.runs_dir``; a ``SuiteError``
    naming what differs when one was evaluated with other settings or conditions (the video size aside: it changes
    no observation; conditions only where the cell recorded them) or has no ``CELL_FILE`` (nothing is deleted)."""
    kept = set()
    for task, source in sources.items():
        expected = cell_record(settings, source)
        expected_conditions = {key: value for key, value in cell_conditions(settings, task).items()
                               if key != "render_size"}
        for demo_set in range(settings.demo_sets):
            cell = cell_dir(settings.runs_dir, task, demo_set)
            if not (cell / "eval_info.json").is_file():
                continue
            if not (cell / CELL_FILE).is_file():
                raise SuiteError(f"--resume: {cell} has no {CELL_FILE} to check its settings against; evaluate "
                                 f"again without --resume, or give this run another --run-name")
            recorded = json.loads((cell / CELL_FILE).read_text())
            recorded.pop("cell", None)  # the cell's seeds and demonstrations, not a setting
            conditions = recorded.pop("conditions", None)
            changed = sorted(key for key in expected.keys() | recorded.keys() if expected.get(key) != recorded.get(key))
            if conditions is not None:
                changed += sorted(key for key, value in expected_conditions.items() if conditions.get(key) != value)
            if changed:
                raise SuiteError(f"--resume: {cell} was evaluated with other settings ({', '.join(changed)}); resume "
                                 f"with the same settings, or give this run another --run-name")
            kept.add((task, demo_set))
    return kept
