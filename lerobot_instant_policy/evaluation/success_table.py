"""Success tables of ``lerobot-eval`` runs: per task, per task group and overall, each rate with two 95% intervals.

Each path is a ``lerobot-eval`` output directory (it holds ``eval_info.json``) or a directory searched recursively
for them. A path may be prefixed ``POLICY=`` to name the policy its runs evaluated; otherwise the policy comes from
the caller's default, else from lerobot-eval's default directory name ``<time>_<env type>_<policy type>``, else it
is ``policy``. The task of a result is its ``task_group`` in ``eval_info.json`` (the env's task name), or, when that
is only the env type, the name of the run directory (of its parent for a demonstration set's ``set-<s>`` folder).
Runs of the same policy and task are pooled: the episodes of every demonstration set count together.

Intervals. Episodes are not independent draws: those of one task share its difficulty, those of one demonstration set
the set's quality. Every rate ``Σ successes / Σ episodes`` therefore carries

* the *cluster* interval (``cluster_ci95_*``, the one to quote): a percentile bootstrap that resamples whole tasks with
  replacement (``BOOTSTRAP_RESAMPLES`` resamples from a generator seeded ``BOOTSTRAP_SEED``, so the same counts give
  the same interval) and takes the 2.5th and 97.5th percentiles of the resampled rate: the uncertainty about the rate
  on other tasks like these. A row of one task resamples its cells instead (``evaluation.manifest``: one
  demonstration set, or one ``lerobot-eval`` run, each); a row with a single cell has none (NaN).
* the *per-episode* interval (``ci95_*``): the Wilson score interval of a binomial proportion
  (``scipy.stats.binomtest(...).proportion_ci``), which treats every episode as an independent draw, so it is
  narrower than the cluster interval wherever tasks differ; it stays inside [0, 1] and is not degenerate at 0 or n
  successes. A column with no success (or no failure) has a cluster interval of zero width; there the per-episode
  interval is the informative one.
"""

from __future__ import annotations

import json
import math
import re
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from .bootstrap import CONFIDENCE, cluster_bootstrap
from .metaworld_suite import SWAP_GROUPS as MT10_KINDS

EVAL_INFO = "eval_info.json"
DEFAULT_ENV_TYPE = "bullet_tabletop"
BOOTSTRAP_RESAMPLES = 10_000
BOOTSTRAP_SEED = 0
OTHER_GROUP = "other"
TASK_UNIT, CELL_UNIT = "task", "cell"  # what a cluster interval resamples (module docstring)
INTERVALS = {
    "cluster_ci95": f"percentile cluster bootstrap resampling tasks (a row of one task: its cells), "
                    f"{BOOTSTRAP_RESAMPLES} resamples, seed {BOOTSTRAP_SEED}; null for a single cluster",
    "ci95": "per episode: Wilson score interval, every episode an independent draw",
}

# The suite's tasks by what a policy must read from its demonstrations; tasks registered from
# outside the package fall in OTHER_GROUP.
TASK_GROUPS: dict[str, tuple[str, ...]] = {
    "one object, one contact or grasp": ("push_button", "knock_over", "pick_and_lift", "lift_lid"),
    "articulated": ("open_drawer", "close_drawer", "open_box", "close_box"),
    "relative placement (two objects)": ("pick_and_place", "put_in_tray", "stack_blocks", "slide_block"),
}
# The rows of a table: the suite's groups, then MetaWorld's MT10 tasks by kind (the swap control's groups).
TABLE_GROUPS: dict[str, tuple[str, ...]] = {**TASK_GROUPS, **{f"MT10, {kind}": tasks for kind, tasks in MT10_KINDS.items()}}


def task_group(task: str) -> str:
    """The group of ``TABLE_GROUPS`` that ``task`` belongs to, else ``OTHER_GROUP``."""
    return next((group for group, tasks in TABLE_GROUPS.items() if task in tasks), OTHER_GROUP)


def wilson_interval(successes: int, episodes: int) -> tuple[float, float]:
    """The Wilson 95% interval ``(low, high)`` of a success rate of ``successes`` in ``episodes``; NaNs for none."""
    if episodes == 0:
        return math.nan, math.nan
    interval = binomtest(successes, episodes).proportion_ci(confidence_level=CONFIDENCE, method="wilson")
    return float(interval.low), float(interval.high)


def cluster_interval(successes, episodes, resamples: int = BOOTSTRAP_RESAMPLES,
                     seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """The percentile bootstrap 95% interval ``(low, high)`` of ``Σ successes / Σ episodes`` over clusters
    (``successes``, ``episodes``: one count per cluster) resampled with replacement; NaNs for fewer than two
    clusters."""
    successes, episodes = np.asarray(successes, dtype=float), np.asarray(episodes, dtype=float)
    return cluster_bootstrap(lambda draws: successes[draws].sum(axis=1) / episodes[draws].sum(axis=1),
                             len(successes), resamples, seed)


@dataclass(frozen=True)
class SuccessCount:
    """``successes`` of ``episodes`` episodes of ``policy`` on ``task`` (a task, a group's name or ``overall``);
    ``cells``: the counts it pools, ``(task, successes, episodes)`` per cell (one demonstration set or
    ``lerobot-eval`` run of a task; a task's whole count where only that is known)."""

    task: str
    policy: str
    episodes: int
    successes: int
    cells: tuple[tuple[str, int, int], ...] = ()

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else math.nan

    @property
    def interval(self) -> tuple[float, float]:
        """The per-episode (Wilson) 95% interval."""
        return wilson_interval(self.successes, self.episodes)

    @property
    def cluster_unit(self) -> str | None:
        """What :attr:`cluster` resamples: tasks, or the cells of a row of one task; ``None`` for one cell."""
        if len({task for task, _, _ in self.cells}) > 1:
            return TASK_UNIT
        return CELL_UNIT if len(self.cells) > 1 else None

    @cached_property
    def cluster(self) -> tuple[float, float]:
        """The cluster bootstrap 95% interval (module docstring): over tasks, or over the cells of one task."""
        if self.cluster_unit == CELL_UNIT:
            return cluster_interval([s for _, s, _ in self.cells], [n for _, _, n in self.cells])
        per_task: dict[str, list[int]] = {}
        for task, successes, episodes in self.cells:
            counts = per_task.setdefault(task, [0, 0])
            counts[0] += successes
            counts[1] += episodes
        return cluster_interval([s for s, _ in per_task.values()], [n for _, n in per_task.values()])

    def as_json(self) -> dict:
        low, high = self.interval
        cluster_low, cluster_high = self.cluster
        return {"task": self.task, "policy": self.policy, "episodes": self.episodes, "successes": self.successes,
                "success_rate": self.success_rate, "cluster_ci95_low": _json_number(cluster_low),
                "cluster_ci95_high": _json_number(cluster_high), "cluster_unit": self.cluster_unit,
                "clusters": self.cluster_count, "ci95_low": low, "ci95_high": high}

    @property
    def cluster_count(self) -> int:
        """How many clusters :attr:`cluster` resamples (tasks, or the cells of one task)."""
        tasks = len({task for task, _, _ in self.cells})
        return tasks if tasks > 1 else len(self.cells)

    def cell(self) -> str:
        """``successes/episodes rate% [cluster low-high] (per-episode low-high)`` for a text table; ``[-]`` where
        there is no cluster interval."""
        low, high = self.interval
        cluster_low, cluster_high = self.cluster
        cluster = "[-]" if math.isnan(cluster_low) else f"[{100 * cluster_low:.0f}-{100 * cluster_high:.0f}]"
        return (f"{self.successes}/{self.episodes} {100 * self.success_rate:.0f}% {cluster} "
                f"({100 * low:.0f}-{100 * high:.0f})")


def _json_number(value: float) -> float | None:
    """``None`` for NaN (JSON has no NaN)."""
    return None if math.isnan(value) else value


def find_eval_infos(path: Path) -> list[Path]:
    """``eval_info.json`` files at or under ``path`` (sorted); an error when there is none."""
    if not path.exists():
        raise FileNotFoundError(f"{path} does not exist")
    if path.is_file():
        found = [path] if path.name == EVAL_INFO else []
    else:
        found = sorted(path.rglob(EVAL_INFO))
    if not found:
        raise FileNotFoundError(f"no {EVAL_INFO} at or under {path}: give lerobot-eval output directories")
    return found


def policy_from_run_name(run_name: str, env_type: str) -> str | None:
    """The policy type in lerobot-eval's default output directory name ``HH-MM-SS_<env type>_<policy type>``."""
    match = re.search(rf"_{re.escape(env_type)}_(.+)$", run_name)
    return match.group(1) if match else None


def load_eval_info(eval_info: Path) -> dict:
    """A lerobot-eval ``eval_info.json``, checked: a ``per_task`` list whose entries have a ``task_group`` and a
    ``metrics.successes`` list (one per episode, in order). ``ValueError`` otherwise."""
    try:
        info = json.loads(eval_info.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{eval_info} is not valid JSON: {error}") from error
    per_task = info.get("per_task") if isinstance(info, dict) else None
    if not isinstance(per_task, list):
        raise ValueError(f"{eval_info} has no 'per_task' list: not a lerobot-eval eval_info.json")
    for entry in per_task:
        successes = entry.get("metrics", {}).get("successes")
        if not isinstance(successes, list) or "task_group" not in entry:
            raise ValueError(f"{eval_info}: a per_task entry lacks 'task_group' or 'metrics.successes'")
    return info


def read_eval_info(eval_info: Path, policy: str | None, env_type: str) -> list[SuccessCount]:
    """One ``SuccessCount`` per task in a lerobot-eval ``eval_info.json`` (its ``per_task`` list)."""
    per_task = load_eval_info(eval_info)["per_task"]
    run_dir = eval_info.parent
    named_dir = run_dir.parent if re.fullmatch(r"set-\d+", run_dir.name) else run_dir
    policy = policy or policy_from_run_name(run_dir.name, env_type) or "policy"
    results = []
    for entry in per_task:
        successes = entry["metrics"]["successes"]
        group = str(entry["task_group"])
        task = named_dir.name if group == env_type else group
        count = int(sum(map(bool, successes)))
        results.append(SuccessCount(task, policy, len(successes), count, ((task, count, len(successes)),)))
    return results


def read_table_rows(table: Path, policy: str | None) -> list[SuccessCount]:
    """The per-task rows of a table this module wrote (``OUT.json``), those of ``policy`` only when given: the
    counts of runs evaluated elsewhere (another machine or session), each task one cluster (its cells are not
    known). ``ValueError`` when it is no such table or has no row of ``policy``."""
    try:
        rows = json.loads(table.read_text()).get("rows")
    except (json.JSONDecodeError, AttributeError) as error:
        raise ValueError(f"{table} is not a success table (lerobot-ip-eval-table's OUT.json): {error}") from error
    keys = ("task", "policy", "episodes", "successes")
    if not isinstance(rows, list) or not all(isinstance(row, dict) and all(key in row for key in keys) for row in rows):
        raise ValueError(f"{table} is not a success table: it needs a 'rows' list of {', '.join(keys)}")
    results = [SuccessCount(str(row["task"]), str(row["policy"]), int(row["episodes"]), int(row["successes"]),
                            ((str(row["task"]), int(row["successes"]), int(row["episodes"])),))
               for row in rows if policy is None or row["policy"] == policy]
    if not results:
        raise ValueError(f"{table} has no rows of policy {policy!r}")
    return results


def path_argument(argument: str) -> tuple[str, Path]:
    """``[POLICY=]PATH`` → ``(POLICY or "", PATH)``."""
    label, separator, path_text = argument.partition("=")
    return (label, Path(path_text)) if separator else ("", Path(argument))


def is_table(path: Path) -> bool:
    """Whether a PATH argument names an earlier table's ``.json`` (not a run directory or its ``eval_info.json``)."""
    return path.suffix == ".json" and path.name != EVAL_INFO


def collect_results(paths: list[str], default_policy: str | None, env_type: str) -> list[SuccessCount]:
    """Pooled counts per (task, policy) over every ``[POLICY=]PATH``, sorted by task then policy. A PATH is a
    lerobot-eval output directory (or a parent of several, or its ``eval_info.json``), or an earlier table's
    ``.json`` (:func:`read_table_rows`: its rows of POLICY, all of them without a prefix, under their own names)."""
    results = []
    for argument in paths:
        label, path = path_argument(argument)
        if is_table(path):
            if not path.is_file():
                raise FileNotFoundError(f"{path} does not exist")
            results += read_table_rows(path, label or None)
        else:
            results += [result for eval_info in find_eval_infos(path)
                        for result in read_eval_info(eval_info, label or default_policy, env_type)]
    return sorted(pool(results, lambda task: task), key=lambda result: (result.task, result.policy))


def pool(results: list[SuccessCount], name_of: Callable[[str], str]) -> list[SuccessCount]:
    """Counts summed and cells gathered per (``name_of(task)``, policy), in first-seen order."""
    pooled: dict[tuple[str, str], list] = {}
    for result in results:
        counts = pooled.setdefault((name_of(result.task), result.policy), [0, 0, ()])
        counts[0] += result.episodes
        counts[1] += result.successes
        counts[2] += result.cells
    return [SuccessCount(name, policy, episodes, successes, cells)
            for (name, policy), (episodes, successes, cells) in pooled.items()]


def policy_means(results: list[SuccessCount]) -> dict[str, float]:
    """Mean over tasks of each policy's success rate (each task weighs the same)."""
    rates: dict[str, list[float]] = defaultdict(list)
    for result in results:
        rates[result.policy].append(result.success_rate)
    return {policy: sum(values) / len(values) for policy, values in rates.items()}


def grouped_tasks(results: list[SuccessCount]) -> list[tuple[str, list[str]]]:
    """``(group, tasks)`` in ``TABLE_GROUPS`` order (``OTHER_GROUP`` last), the tasks present in ``results`` only."""
    present = {result.task for result in results}
    groups = [(group, [task for task in tasks if task in present]) for group, tasks in TABLE_GROUPS.items()]
    others = sorted(task for task in present if task_group(task) == OTHER_GROUP)
    return [(group, tasks) for group, tasks in groups + [(OTHER_GROUP, others)] if tasks]


def format_table(results: list[SuccessCount]) -> str:
    """A text table, one column per policy: each task grouped as ``TABLE_GROUPS``, each group pooled, then every
    episode pooled (``overall``); each cell ``successes/episodes rate% [cluster 95% interval] (per-episode 95%
    interval)`` (module docstring), explained below the table."""
    policies = sorted({result.policy for result in results})
    by_key = {(result.task, result.policy): result for result in results}
    group_counts = {(result.task, result.policy): result for result in pool(results, task_group)}
    overall = {result.policy: result for result in pool(results, lambda task: "overall")}
    rows = [("task", *policies)]
    for group, tasks in grouped_tasks(results):
        rows.append((f"[{group}]", *(group_counts[(group, policy)].cell() if (group, policy) in group_counts
                                     else "-" for policy in policies)))
        rows += [(f"  {task}", *(by_key[(task, policy)].cell() if (task, policy) in by_key else "-"
                                 for policy in policies)) for task in tasks]
    rows.append(("overall (every episode)", *(overall[policy].cell() for policy in policies)))
    widths = [max(len(row[column]) for row in rows) for column in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True)) for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    return "\n".join([*lines, "", LEGEND])


LEGEND = ("[low-high]: 95% cluster bootstrap over tasks (a task's own row: over its cells; [-]: one cell); "
          "(low-high): 95% Wilson interval per episode")


def results_json(results: list[SuccessCount]) -> dict:
    """The table as JSON: per (task, policy), per (group, policy) and per policy overall, each with its counts,
    ``success_rate`` in [0, 1], its cluster interval (``cluster_ci95_*``, over ``clusters`` of ``cluster_unit``)
    and its per-episode Wilson interval (``ci95_*``); ``mean_success_rate``: each policy's mean over tasks;
    ``intervals``: what each interval is."""
    tasks_of = dict(grouped_tasks(results))
    return {
        "rows": [result.as_json() for result in results],
        "groups": [{**result.as_json(), "group": result.task, "tasks": tasks_of[result.task]}
                   for result in pool(results, task_group)],
        "overall": {result.policy: result.as_json() for result in pool(results, lambda task: "overall")},
        "mean_success_rate": policy_means(results),
        "confidence": CONFIDENCE,
        "intervals": INTERVALS,
    }


def save_bar_chart(results: list[SuccessCount], path: Path, title: str = "success per task") -> None:
    """Grouped bars, one group per task (in ``TABLE_GROUPS`` order) and one for all tasks pooled, one bar per policy,
    success rate in %: the thick error bar is the cluster 95% interval (all tasks: over tasks; one task: over its
    cells), the thin grey one beside it the per-episode Wilson interval; episodes above each bar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    all_tasks = "all tasks"
    tasks = [task for _, group_tasks in grouped_tasks(results) for task in group_tasks]
    policies = sorted({result.policy for result in results})
    by_key = {(result.task, result.policy): result for result in results}
    by_key.update({(all_tasks, result.policy): result for result in pool(results, lambda task: all_tasks)})
    columns = [*tasks, all_tasks]
    width = 0.8 / len(policies)
    figure, axes = plt.subplots(figsize=(max(6.0, 1.0 + 0.9 * len(columns) * max(1, len(policies)) ** 0.5), 4.2))
    for index, policy in enumerate(policies):
        offsets = np.array([position - 0.4 + width * (index + 0.5) for position in range(len(columns))])
        counts = [by_key.get((task, policy)) for task in columns]
        heights = np.array([100 * count.success_rate if count else 0.0 for count in counts])
        bars = axes.bar(offsets, heights, width=width, label=policy)
        for intervals, shift, style in (([count.cluster if count else (math.nan, math.nan) for count in counts], 0.0,
                                         {"color": "black", "elinewidth": 1.2, "capsize": 2}),
                                        ([count.interval if count else (math.nan, math.nan) for count in counts],
                                         width * 0.3, {"color": "0.55", "elinewidth": 0.7, "capsize": 0})):
            low, high = (100 * np.array([interval[side] for interval in intervals]) for side in (0, 1))
            shown = ~np.isnan(low)
            if shown.any():
                axes.errorbar(offsets[shown] + shift, heights[shown], fmt="none",
                              yerr=np.vstack([heights[shown] - low[shown], high[shown] - heights[shown]]), **style)
        for bar, count in zip(bars, counts, strict=True):
            if count is not None:
                axes.annotate(f"n={count.episodes}", (bar.get_x() + bar.get_width() / 2, 1.0), ha="center",
                              va="bottom", fontsize=6, rotation=90)
    axes.axvline(len(tasks) - 0.5, color="0.7", linewidth=0.8)
    axes.set_xticks(range(len(columns)), columns, rotation=30, ha="right")
    axes.set_ylabel("success rate (%)")
    axes.set_ylim(0, 110)
    axes.set_title(f"{title}\nblack: 95% cluster interval (all tasks: over tasks; a task: over its demonstration sets), "
                   f"grey: per episode (Wilson)", fontsize=8)
    axes.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def write_table(results: list[SuccessCount], out: Path, title: str) -> tuple[Path, Path]:
    """Write ``out.json`` (``results_json``) and ``out.png`` (``save_bar_chart``); returns both paths."""
    json_path, png_path = out.with_suffix(".json"), out.with_suffix(".png")
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(results_json(results), indent=2) + "\n")
    save_bar_chart(results, png_path, title=title)
    return json_path, png_path
