"""``lerobot-ip-demo`` (``make demo``): teach one ``bullet_tabletop`` task with 2 demonstrations and evaluate
(``evaluation.demo``).

Runs ``instant_policy`` the paper's way (``--checkpoint``, default the one shipped in the package), the same network
run from the per-object replay of its demonstrations (``--replay-prior-checkpoint``, default the one shipped beside
it), each when present, and the classical ``demo_replay`` baseline for ``--episodes`` episodes each through
``lerobot-eval``, on the same scenes.
Prints their success per episode side by side, each column's test-split figure on the task beside them (from the
checkout's ``docs/results_suite_test.json``), and writes a contact sheet (first and last frame of every episode,
framed by its outcome) beside the videos. Exits with 1 when the headline column (the recommended policy among those
run: the replay-prior checkpoint where present) failed every episode; a compared column failing is what the task
shows.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..configuration_instant_policy import SHIPPED_CHECKPOINT, SHIPPED_REPLAY_PRIOR_CHECKPOINT
from ..evaluation.demo import (
    DEFAULT_TASK,
    POLICY_CHOICES,
    TEST_SPLIT_TABLE,
    headline_failure,
    policies_to_run,
    run_demo,
    test_split_figures,
)
from ..evaluation.side_by_side import draw_contact_sheet, summary_table
from ..evaluation.suite import SuiteError


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default=DEFAULT_TASK)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_CHECKPOINT,
                        help="instant_policy pretrained_model run the paper's way (from pure noise)")
    parser.add_argument("--replay-prior-checkpoint", type=Path, default=SHIPPED_REPLAY_PRIOR_CHECKPOINT,
                        help="instant_policy pretrained_model whose config runs it from the replay prior")
    parser.add_argument("--policy", choices=POLICY_CHOICES, default="auto",
                        help="auto: instant_policy from both checkpoints (those present) and demo_replay, side by side")
    parser.add_argument("--out", type=Path, default=Path("outputs/demo"))
    args = parser.parse_args(argv)
    policies, reason = policies_to_run(args.policy, args.checkpoint, args.replay_prior_checkpoint)
    print(f"policies: {', '.join(column.name for column in policies)} ({reason})", flush=True)
    try:
        outcomes = run_demo(args.task, policies, args.episodes, args.batch_size, args.out,
                            report=lambda line: print(line, flush=True))
    except (SuiteError, ValueError, RuntimeError) as error:
        print(f"lerobot-ip-demo: error: {error}", file=sys.stderr)
        return 2
    print(summary_table(args.task, outcomes))
    figures = test_split_figures(args.task, policies)
    if figures:
        print(f"test split on {args.task} ({TEST_SPLIT_TABLE}: 3 demonstration sets x 10 episodes): "
              + ", ".join(f"{name} {figure}" for name, figure in figures.items()))
    sheet = draw_contact_sheet(args.task, outcomes, args.out / f"contact_sheet_{args.task}.png")
    print(f"contact sheet (first and last frame of every episode): {sheet}")
    videos = [str(episode.video) for episodes in outcomes.values() for episode in episodes if episode.video]
    print("videos:\n  " + "\n  ".join(videos))
    failed = headline_failure(outcomes)
    if failed:
        print(f"lerobot-ip-demo: {failed}, the recommended policy, failed every episode of {args.task}",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
