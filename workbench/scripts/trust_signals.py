"""Whether a replay plan's trust (:mod:`lerobot_instant_policy.replay.trust`: its registration's fit, the
demonstrations' disagreement) tells the plans that are wrong in their scene from those that are right, where ground
truth exists (:func:`~lerobot_instant_policy.replay.segments.plan_is_wrong` against the live demonstration).

    python -m workbench.scripts.trust_signals outputs/results/suite_dev/demos [--plans anchored,per_object]

``DEMOS`` holds the demonstration sets an evaluation recorded (``<task>-n<N>-s<seed>``, as
``python -m workbench.cli.replay_error`` reads them). Each episode of a set is the live scene in turn and the next set
of its task (the last set's: the first) its context, as an evaluation hands one set to the policy. Prints JSON: per
plan, the wrong plans' share, and per signal the separation (the probability that a wrong plan's signal exceeds a
right one's, ties half: 0.5 tells nothing, 1 separates them), the signal's quartiles among right and wrong plans, and
per task the wrong count and the median signal.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from lerobot_instant_policy.replay.plan import REPLAY_REGISTRATION, best_plan, plan_each
from lerobot_instant_policy.replay.segments import plan_is_wrong
from lerobot_instant_policy.replay.trust import plan_trust
from workbench.cli.replay_error import demonstration_sets

SIGNALS = ("fit_m", "disagreement_m", "distrust_m")


def separation(wrong: np.ndarray, right: np.ndarray) -> float | None:
    """P(a wrong plan's signal > a right plan's), ties counted half (the Mann-Whitney AUC); None without both."""
    if not len(wrong) or not len(right):
        return None
    greater = (wrong[:, None] > right[None, :]).mean()
    ties = (wrong[:, None] == right[None, :]).mean()
    return round(float(greater + 0.5 * ties), 3)


def scene_records(demos: Path, plans: list[str]) -> list[dict]:
    records = []
    for task, sets in demonstration_sets(demos).items():
        for index, live_set in enumerate(sets):
            context = sets[(index + 1) % len(sets)]
            for live in live_set:
                for plan in plans:  # the plan executed, judged as evaluation.replay_error judges it
                    candidates = plan_each(task, context, live.points_world[0], REPLAY_REGISTRATION, plan)
                    chosen = best_plan(candidates)
                    trust = plan_trust(candidates, chosen)
                    records.append({"task": task, "plan": plan, "wrong": plan_is_wrong(chosen.actions, live.action),
                                    "fit_m": trust.fit_m, "disagreement_m": trust.disagreement_m,
                                    "distrust_m": trust.distrust_m})
    return records


def summary(records: list[dict]) -> dict:
    wrong = np.array([record["wrong"] for record in records])
    result = {"scenes": len(records), "wrong": int(wrong.sum())}
    for signal in SIGNALS:
        values = np.array([record[signal] for record in records]) * 1000.0
        result[signal] = {
            "separation": separation(values[wrong], values[~wrong]),
            "right_mm_quartiles": np.round(np.percentile(values[~wrong], [25, 50, 75]), 1).tolist() if (~wrong).any()
            else None,
            "wrong_mm_quartiles": np.round(np.percentile(values[wrong], [25, 50, 75]), 1).tolist() if wrong.any()
            else None,
        }
    tasks = sorted({record["task"] for record in records})
    result["per_task"] = {
        task: {"wrong": int(sum(record["wrong"] for record in records if record["task"] == task)),
               "scenes": sum(record["task"] == task for record in records),
               "median_distrust_mm": round(1000.0 * float(np.median(
                   [record["distrust_m"] for record in records if record["task"] == task])), 1)}
        for task in tasks}
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("demos", type=Path)
    parser.add_argument("--plans", default="anchored,per_object")
    parser.add_argument("--records", type=Path, help="also write every scene's record here (JSON)")
    args = parser.parse_args()
    plans = args.plans.split(",")
    records = scene_records(args.demos, plans)
    if args.records:
        args.records.write_text(json.dumps(records, indent=1))
    print(json.dumps({"demos": str(args.demos),
                      "plans": {plan: summary([record for record in records if record["plan"] == plan])
                                for plan in plans}}, indent=2))


if __name__ == "__main__":
    main()
