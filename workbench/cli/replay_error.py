"""``python -m workbench.cli.replay_error`` (from the repository root): the error of each replay plan against the
demonstration recorded in the same live scene (:mod:`lerobot_instant_policy.evaluation.replay_error`), over the
demonstration sets an evaluation recorded, printed as JSON.

    python -m workbench.cli.replay_error outputs/results/suite_dev/demos --plans whole,per_object,anchored

``DEMOS`` holds one LeRobot dataset per task and demonstration set, as ``lerobot-ip-eval-suite`` and
``lerobot-ip-eval-metaworld`` record them (``<task>-n<N>-s<seed>``). Each episode of set ``s`` is the live scene in
turn, and the episodes of the next set of the same task (``s + 1``, the last set's the first's) are its context, as
an evaluation hands a set to the policy: the context never holds the live scene's own demonstration.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import defaultdict
from pathlib import Path

from lerobot_instant_policy.data.demonstrations import open_demo_dataset, read_demonstration
from lerobot_instant_policy.data.replay_plan import REPLAY_PLANS
from lerobot_instant_policy.evaluation.replay_error import error_quantiles, plan_error

PROG = "python -m workbench.cli.replay_error"
SET_FOLDER = re.compile(r"^(?P<task>.+)-n(?P<n>\d+)-s(?P<seed>\d+)$")


def demonstration_sets(demos: Path) -> dict[str, list]:
    """``{task: [[Demonstration, ...] per set, in seed order]}`` of the dataset folders under ``demos``."""
    folders = defaultdict(list)
    for folder in sorted(demos.iterdir()):
        match = SET_FOLDER.match(folder.name)
        if match and (folder / "meta" / "info.json").is_file():
            folders[match["task"]].append((int(match["seed"]), folder))
    sets = {}
    for task, found in sorted(folders.items()):
        sets[task] = []
        for _, folder in sorted(found):
            dataset = open_demo_dataset(f"local/{task}", folder)
            sets[task].append([read_demonstration(dataset, int(episode["episode_index"]), task)
                               for episode in dataset.meta.episodes])
    return sets


def replay_errors(sets: dict[str, list], plans: list[str]) -> dict:
    """Per plan: the pooled :func:`error_quantiles` and each task's (module docstring)."""
    errors = {plan: defaultdict(list) for plan in plans}
    for task, task_sets in sets.items():
        if len(task_sets) < 2:
            continue
        for index, live_set in enumerate(task_sets):
            context = task_sets[(index + 1) % len(task_sets)]
            for live in live_set:
                for plan in plans:
                    errors[plan][task].append(plan_error(context, live, plan))
    return {plan: {"all": error_quantiles([error for task in by_task.values() for error in task]),
                   "per_task": {task: error_quantiles(task_errors) for task, task_errors in by_task.items()}}
            for plan, by_task in errors.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("demos", type=Path, help="a folder of demonstration sets (<task>-n<N>-s<seed>)")
    parser.add_argument("--plans", default=",".join(REPLAY_PLANS),
                        help=f"comma-separated replay plans (default: {','.join(REPLAY_PLANS)})")
    args = parser.parse_args(argv)
    plans = args.plans.split(",")
    unknown = [plan for plan in plans if plan not in REPLAY_PLANS]
    if unknown or not args.demos.is_dir():
        print(f"{PROG}: error: " + (f"unknown plans {unknown}: expected {list(REPLAY_PLANS)}" if unknown
                                    else f"{args.demos} is not a folder"), file=sys.stderr)
        return 2
    sets = demonstration_sets(args.demos)
    if not any(len(task_sets) >= 2 for task_sets in sets.values()):
        print(f"{PROG}: error: {args.demos} holds no task with two demonstration sets", file=sys.stderr)
        return 2
    print(json.dumps({"demos": str(args.demos), "tasks": {task: len(task_sets) for task, task_sets in sets.items()},
                      "plans": replay_errors(sets, plans)}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
