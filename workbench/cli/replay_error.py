"""``python -m workbench.cli.replay_error`` (from the repository root): the error of each replay plan against the
demonstration recorded in the same live scene (:mod:`lerobot_instant_policy.evaluation.replay_error`), over the
demonstration sets an evaluation recorded, printed as JSON.

    python -m workbench.cli.replay_error outputs/results/suite_dev/demos --plans whole,per_object,anchored

``DEMOS`` holds one LeRobot dataset per task and demonstration set, as ``lerobot-ip-eval-suite`` and
``lerobot-ip-eval-metaworld`` record them (``<task>-n<N>-s<seed>``). Each episode of set ``s`` is the live scene in
turn, and the episodes of the next set of the same task (``s + 1``, the last set's the first's) are its context, as
an evaluation hands a set to the policy: the context never holds the live scene's own demonstration. With
``--within-set`` the context is instead the other episodes of the live scene's own set, for evaluations that
recorded one set per task (MetaWorld's dev split):

    python -m workbench.cli.replay_error outputs/results/mt10_dev/demos --within-set

    python -m workbench.cli.replay_error outputs/standing/validation/moved --pseudo-tasks 96

With ``--pseudo-tasks N``, ``DEMOS`` is one pseudo-demonstration dataset (``lerobot-ip-generate``'s; a task's
episodes share its ``task`` string) and its first ``N`` tasks are measured as training plans its replay prior: the
last episode is the live demonstration, the first ``--context`` episodes (1, as the stream plans the prior) the
context. Printed beside a suite's figures, the two say whether the priors a corrector trains on err as the replays
it meets do: at the bottlenecks, and as the training loss sees them (``prior_vs_holding_still``, per third of the
live episode).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import defaultdict
from pathlib import Path

from lerobot_instant_policy.data.demonstrations import episodes_by_task, open_demo_dataset, read_demonstration
from lerobot_instant_policy.evaluation.replay_error import error_quantiles, plan_error
from lerobot_instant_policy.replay.plan import REPLAY_PLANS

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


def replay_errors(sets: dict[str, list], plans: list[str], within_set: bool = False) -> dict:
    """Per plan: the pooled :func:`error_quantiles` and each task's (module docstring), each live scene planned from
    the next set's episodes or, ``within_set``, from the other episodes of its own set."""
    errors = {plan: defaultdict(list) for plan in plans}
    for task, task_sets in sets.items():
        for index, live_set in enumerate(task_sets):
            next_set = task_sets[(index + 1) % len(task_sets)] if len(task_sets) > 1 else []
            for number, live in enumerate(live_set):
                context = live_set[:number] + live_set[number + 1:] if within_set else next_set
                if not context:
                    continue
                for plan in plans:
                    errors[plan][task].append(plan_error(context, live, plan))
    return {plan: {"all": error_quantiles([error for task in by_task.values() for error in task]),
                   "per_task": {task: error_quantiles(task_errors) for task, task_errors in by_task.items()}}
            for plan, by_task in errors.items()}


def pseudo_task_errors(root: Path, num_tasks: int, context_demos: int, plans: list[str]) -> dict:
    """Per plan: the pooled :func:`error_quantiles` over the first ``num_tasks`` pseudo-tasks of the dataset at
    ``root`` (module docstring); ``ValueError`` where it holds fewer with ``context_demos`` + 1 episodes."""
    dataset = open_demo_dataset("local/pseudo_tasks", root)
    usable = [(task, episodes) for task, episodes in episodes_by_task(dataset) if len(episodes) > context_demos]
    if len(usable) < num_tasks:
        raise ValueError(f"{root} holds {len(usable)} pseudo-tasks with {context_demos + 1} episodes or more, "
                         f"asked for {num_tasks}")
    errors = {plan: [] for plan in plans}
    for task, episodes in usable[:num_tasks]:
        demos = [read_demonstration(dataset, index, task) for index in episodes[:context_demos] + episodes[-1:]]
        for plan in plans:
            errors[plan].append(plan_error(demos[:-1], demos[-1], plan))
    return {plan: {"all": error_quantiles(plan_errors)} for plan, plan_errors in errors.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    parser.add_argument("demos", type=Path, help="a folder of demonstration sets (<task>-n<N>-s<seed>)")
    parser.add_argument("--plans", default=",".join(REPLAY_PLANS),
                        help=f"comma-separated replay plans (default: {','.join(REPLAY_PLANS)})")
    parser.add_argument("--pseudo-tasks", type=int, metavar="N",
                        help="DEMOS is a pseudo-demonstration dataset: measure its first N tasks' replay priors")
    parser.add_argument("--context", type=int, default=1,
                        help="with --pseudo-tasks, the context episodes a prior is planned from (default 1)")
    parser.add_argument("--within-set", action="store_true",
                        help="plan each live scene from the other episodes of its own set, not from the next set")
    args = parser.parse_args(argv)
    plans = args.plans.split(",")
    unknown = [plan for plan in plans if plan not in REPLAY_PLANS]
    if unknown or not args.demos.is_dir():
        print(f"{PROG}: error: " + (f"unknown plans {unknown}: expected {list(REPLAY_PLANS)}" if unknown
                                    else f"{args.demos} is not a folder"), file=sys.stderr)
        return 2
    if args.pseudo_tasks is not None:
        try:
            if args.pseudo_tasks < 1 or args.context < 1:
                raise ValueError(f"--pseudo-tasks and --context must be at least 1, got {args.pseudo_tasks}, "
                                 f"{args.context}")
            plans_errors = pseudo_task_errors(args.demos, args.pseudo_tasks, args.context, plans)
        except (ValueError, FileNotFoundError) as error:
            print(f"{PROG}: error: {error}", file=sys.stderr)
            return 2
        print(json.dumps({"demos": str(args.demos), "pseudo_tasks": args.pseudo_tasks, "context": args.context,
                          "plans": plans_errors}, indent=2))
        return 0
    sets = demonstration_sets(args.demos)
    if args.within_set and not any(len(live_set) >= 2 for task_sets in sets.values() for live_set in task_sets):
        print(f"{PROG}: error: {args.demos} holds no demonstration set of two episodes", file=sys.stderr)
        return 2
    if not args.within_set and not any(len(task_sets) >= 2 for task_sets in sets.values()):
        print(f"{PROG}: error: {args.demos} holds no task with two demonstration sets", file=sys.stderr)
        return 2
    print(json.dumps({"demos": str(args.demos), "tasks": {task: len(task_sets) for task, task_sets in sets.items()},
                      "within_set": args.within_set, "plans": replay_errors(sets, plans, args.within_set)},
                     indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
