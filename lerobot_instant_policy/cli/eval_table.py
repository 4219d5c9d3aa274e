"""``lerobot-ip-eval-table``: per-task success table of ``lerobot-eval`` runs, as text, JSON and a bar chart.

Each path is a ``lerobot-eval`` output directory (it holds ``eval_info.json``) or a directory searched
recursively for them. A path may be prefixed ``POLICY=`` to name the policy its runs evaluated; otherwise the
policy comes from ``--policy``, else from lerobot-eval's default directory name ``<time>_<env type>_<policy
type>``, else it is ``policy``. The task of a result is its ``task_group`` in ``eval_info.json`` (the env's
task name), or, when that is only the env type, the name of the run directory. Runs of the same policy and
task are pooled.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections import defaultdict
from dataclasses import asdict, dataclass
from pathlib import Path

EVAL_INFO = "eval_info.json"
DEFAULT_ENV_TYPE = "bullet_tabletop"


@dataclass(frozen=True)
class TaskResult:
    """Success of ``policy`` on ``task`` over ``episodes`` episodes (``successes`` of them succeeded)."""

    task: str
    policy: str
    episodes: int
    successes: int

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else math.nan


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


def read_eval_info(eval_info: Path, policy: str | None, env_type: str) -> list[TaskResult]:
    """One ``TaskResult`` per task in a lerobot-eval ``eval_info.json`` (its ``per_task`` list)."""
    per_task = load_eval_info(eval_info)["per_task"]
    run_name = eval_info.parent.name
    policy = policy or policy_from_run_name(run_name, env_type) or "policy"
    results = []
    for entry in per_task:
        successes = entry["metrics"]["successes"]
        group = str(entry["task_group"])
        task = run_name if group == env_type else group
        results.append(TaskResult(task=task, policy=policy, episodes=len(successes), successes=int(sum(map(bool, successes)))))
    return results


def collect_results(paths: list[str], default_policy: str | None, env_type: str) -> list[TaskResult]:
    """Pooled results per (task, policy) over every ``[POLICY=]PATH``, sorted by task then policy."""
    pooled: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    for argument in paths:
        label, separator, path_text = argument.partition("=")
        if not separator:
            label, path_text = "", argument
        policy = label or default_policy
        for eval_info in find_eval_infos(Path(path_text)):
            for result in read_eval_info(eval_info, policy, env_type):
                counts = pooled[(result.task, result.policy)]
                counts[0] += result.episodes
                counts[1] += result.successes
    return [
        TaskResult(task=task, policy=policy, episodes=episodes, successes=successes)
        for (task, policy), (episodes, successes) in sorted(pooled.items())
    ]


def policy_means(results: list[TaskResult]) -> dict[str, float]:
    """Mean over tasks of each policy's success rate (each task weighs the same)."""
    rates: dict[str, list[float]] = defaultdict(list)
    for result in results:
        rates[result.policy].append(result.success_rate)
    return {policy: sum(values) / len(values) for policy, values in rates.items()}


def format_table(results: list[TaskResult]) -> str:
    """A plain-text table: task, policy, episodes, success rate (%); then each policy's mean over tasks."""
    rows = [("task", "policy", "episodes", "success %")]
    rows += [(r.task, r.policy, str(r.episodes), f"{100 * r.success_rate:.1f}") for r in results]
    rows += [("mean over tasks", policy, "", f"{100 * mean:.1f}") for policy, mean in policy_means(results).items()]
    widths = [max(len(row[column]) for row in rows) for column in range(4)]
    lines = [
        "  ".join(cell.ljust(width) if column < 2 else cell.rjust(width) for column, (cell, width) in enumerate(zip(row, widths)))
        for row in rows
    ]
    lines.insert(1, "  ".join("-" * width for width in widths))
    return "\n".join(lines)


def results_json(results: list[TaskResult]) -> dict:
    """The table as JSON: one row per (task, policy) with ``success_rate`` in [0, 1], and the policies' means."""
    return {
        "rows": [{**asdict(result), "success_rate": result.success_rate} for result in results],
        "mean_success_rate": policy_means(results),
    }


def save_bar_chart(results: list[TaskResult], path: Path, title: str = "success per task") -> None:
    """Grouped bars: one group per task, one bar per policy, success rate in %, episodes above each bar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = sorted({result.task for result in results})
    policies = sorted({result.policy for result in results})
    by_key = {(result.task, result.policy): result for result in results}
    width = 0.8 / len(policies)
    figure, axes = plt.subplots(figsize=(max(6.0, 1.0 + 0.9 * len(tasks) * max(1, len(policies)) ** 0.5), 4.0))
    for index, policy in enumerate(policies):
        offsets = [position - 0.4 + width * (index + 0.5) for position in range(len(tasks))]
        heights = [100 * by_key[(task, policy)].success_rate if (task, policy) in by_key else 0.0 for task in tasks]
        bars = axes.bar(offsets, heights, width=width, label=policy)
        for bar, task in zip(bars, tasks):
            if (task, policy) in by_key:
                axes.annotate(
                    f"n={by_key[(task, policy)].episodes}", (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                    ha="center", va="bottom", fontsize=7,
                )
    axes.set_xticks(range(len(tasks)), tasks, rotation=30, ha="right")
    axes.set_ylabel("success rate (%)")
    axes.set_ylim(0, 110)
    axes.set_title(title)
    axes.legend()
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lerobot-ip-eval-table",
        description="Per-task success table of lerobot-eval runs (text or JSON on stdout, JSON and PNG files).",
    )
    parser.add_argument("paths", nargs="+", help="[POLICY=]DIR: a lerobot-eval output dir or a parent of several")
    parser.add_argument("--policy", default=None, help="policy name for paths without a POLICY= prefix")
    parser.add_argument("--env-type", default=DEFAULT_ENV_TYPE, help="env type lerobot-eval ran (default: %(default)s)")
    parser.add_argument("--out", default="eval_table", help="writes OUT.json and OUT.png (default: %(default)s)")
    parser.add_argument("--json", action="store_true", help="print the table as JSON instead of text")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        results = collect_results(args.paths, args.policy, args.env_type)
    except (FileNotFoundError, ValueError) as error:
        print(f"lerobot-ip-eval-table: {error}", file=sys.stderr)
        return 2
    table = results_json(results)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(table, indent=2) + "\n")
    save_bar_chart(results, out.with_suffix(".png"), title=f"{args.env_type}: success per task")
    print(json.dumps(table) if args.json else format_table(results))
    if not args.json:
        print(f"\nwrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
