"""``make demo``: teach one ``bullet_tabletop`` task with 2 demonstrations and evaluate, policies side by side.

Records 2 scripted demonstrations of the task and runs ``instant_policy`` (when a checkpoint is present, by default
the one shipped in the package) and the classical ``demo_replay`` baseline through ``lerobot-eval`` on the same
scenes (the same seeds); ``evaluation.side_by_side`` tabulates their episodes and draws the contact sheet.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from .side_by_side import EpisodeOutcome, episode_outcomes, success_percent
from .suite import SuiteSettings, run_task

DEFAULT_TASK = "pick_and_lift"
POLICY_CHOICES = ("auto", "instant_policy", "demo_replay", "do_nothing")


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


def run_demo(task: str, policies: list[tuple[str, str | None]], episodes: int, batch_size: int, out: Path,
             report: Callable[[str], None] = print) -> dict[str, list[EpisodeOutcome]]:
    """Each ``(policy, checkpoint)`` on ``task`` for ``episodes`` episodes (one demonstration set, the same seeds for
    all); returns each policy's episodes in order."""
    outcomes: dict[str, list[EpisodeOutcome]] = {}
    for policy, policy_path in policies:
        settings = SuiteSettings(policy=policy, policy_path=policy_path, out=out, episodes=episodes, demo_sets=1,
                                 batch_size=batch_size)
        settings.validate()
        outcomes[policy] = episode_outcomes(run_task(settings, task), settings.eval_seed_of(0))
        report(f"task {task}: {policy} succeeded in {success_percent(outcomes[policy]):.0f}% of "
               f"{len(outcomes[policy])} episodes")
    return outcomes


def failed_policies(outcomes: dict[str, list[EpisodeOutcome]]) -> list[str]:
    """The policies that read demonstrations and succeeded in no episode: a demo that shows nothing."""
    return [policy for policy, episodes in outcomes.items()
            if policy != "do_nothing" and not any(episode.success for episode in episodes)]
