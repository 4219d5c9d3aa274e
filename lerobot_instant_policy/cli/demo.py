"""``lerobot-ip-demo`` (``make demo``): teach one ``bullet_tabletop`` task with 2 demonstrations and evaluate.

Records 2 scripted demonstrations of ``--task`` and runs ``instant_policy`` (when a checkpoint is present:
``--checkpoint``, default the one shipped in the package) and the classical ``demo_replay`` baseline for
``--episodes`` episodes each through ``lerobot-eval``, on the same scenes (the same seeds). Prints their success per
episode side by side, and writes a contact sheet (first and last frame of every episode, framed by its outcome)
beside the videos.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .demo_summary import EpisodeOutcome, draw_contact_sheet, episode_outcomes, success_percent, summary_table
from .eval_suite import SuiteSettings, run_task

SHIPPED_CHECKPOINT = Path(__file__).resolve().parents[1] / "assets" / "checkpoints" / "instant_policy"
DEFAULT_TASK = "pick_and_lift"


def best_policy(checkpoint: Path) -> tuple[str, str | None, str]:
    """``(policy type, checkpoint or None, reason)``."""
    from lerobot.configs.policies import PreTrainedConfig

    if not (checkpoint / "config.json").is_file():
        return "demo_replay", None, f"no instant_policy checkpoint at {checkpoint}"
    if "instant_policy" not in PreTrainedConfig.get_known_choices():
        return "demo_replay", None, "the instant_policy policy is not installed in this version"
    return "instant_policy", str(checkpoint), f"checkpoint {checkpoint}"


def policies_to_run(choice: str, checkpoint: Path) -> tuple[list[tuple[str, str | None]], str]:
    """``([(policy type, checkpoint or None), ...], reason)``: ``auto`` runs ``instant_policy`` (when a checkpoint
    and the policy are there) beside ``demo_replay`` on the same scenes; any other choice runs that policy alone."""
    if choice != "auto":
        return [(choice, str(checkpoint) if choice == "instant_policy" else None)], "--policy"
    policy, policy_path, reason = best_policy(checkpoint)
    return ([(policy, policy_path)] if policy == "instant_policy" else []) + [("demo_replay", None)], reason


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default=DEFAULT_TASK)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_CHECKPOINT, help="instant_policy pretrained_model")
    parser.add_argument(
        "--policy",
        choices=("auto", "instant_policy", "demo_replay", "do_nothing"),
        default="auto",
        help="auto: instant_policy from --checkpoint (when there is one) and demo_replay, side by side",
    )
    parser.add_argument("--out", type=Path, default=Path("outputs/demo"))
    args = parser.parse_args(argv)
    policies, reason = policies_to_run(args.policy, args.checkpoint)
    print(f"policies: {', '.join(policy for policy, _ in policies)} ({reason})", flush=True)
    outcomes: dict[str, list[EpisodeOutcome]] = {}
    for policy, policy_path in policies:
        settings = SuiteSettings(
            policy=policy, policy_path=policy_path, out=args.out, episodes=args.episodes, batch_size=args.batch_size
        )
        try:
            output_dir = run_task(settings, args.task)
        except (ValueError, RuntimeError) as error:
            print(f"lerobot-ip-demo: error: {error}", file=sys.stderr)
            return 2
        outcomes[policy] = episode_outcomes(output_dir, settings.eval_seed)
        rate, episodes = success_percent(outcomes[policy]), len(outcomes[policy])
        print(f"task {args.task}: {policy} succeeded in {rate:.0f}% of {episodes} episodes", flush=True)
    print(summary_table(args.task, outcomes))
    sheet = draw_contact_sheet(args.task, outcomes, args.out / f"contact_sheet_{args.task}.png")
    print(f"contact sheet (first and last frame of every episode): {sheet}")
    videos = [str(episode.video) for episodes in outcomes.values() for episode in episodes if episode.video]
    print("videos:\n  " + "\n  ".join(videos))
    return 0


if __name__ == "__main__":
    sys.exit(main())
