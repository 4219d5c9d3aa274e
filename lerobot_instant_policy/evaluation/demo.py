"""``make demo``: teach one ``bullet_tabletop`` task with 2 demonstrations and evaluate, policies side by side.

Records 2 scripted demonstrations of the task and runs, through ``lerobot-eval`` on the same scenes (the same seeds),
``instant_policy`` the paper's way (from pure noise) and from the per-object replay of its demonstrations (the two
checkpoints shipped in the package, when present) and the classical ``demo_replay`` baseline;
``evaluation.side_by_side`` tabulates their episodes and draws the contact sheet. Beside its own few episodes it reads
each column's test-split figure on the task from the suite's committed success table (:func:`test_split_figures`).
The default task, ``close_box``, is one where the learned correction matters on the test split: the network from the
replay 30/30, the replay alone 15/30, the paper's inference 12/30.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..configuration_instant_policy import SHIPPED_CHECKPOINT, SHIPPED_REPLAY_PRIOR_CHECKPOINT
from .side_by_side import EpisodeOutcome, episode_outcomes, success_percent
from .suite import SuiteSettings, run_task

DEFAULT_TASK = "close_box"
REPLAY_PRIOR = "instant_policy_replay_prior"  # the demo's name for instant_policy run from the replay prior
# the suite's test-split success table in a checkout, and the column of each demo policy in it
TEST_SPLIT_TABLE = Path("docs/results_suite_test.json")
TEST_SPLIT_COLUMNS = {"instant_policy": "instant_policy", REPLAY_PRIOR: "ip_per_object_s0125_K8",
                      "demo_replay": "demo_replay", "do_nothing": "do_nothing"}
POLICY_CHOICES = ("auto", "instant_policy", REPLAY_PRIOR, "demo_replay", "do_nothing")
# the column the demo stands on, the first of these that ran: the recommended policy (README's "Which to use when")
HEADLINE_ORDER = (REPLAY_PRIOR, "instant_policy", "demo_replay")


@dataclass(frozen=True)
class DemoPolicy:
    """One column of the demo: its ``name`` (the run's name), the ``lerobot-eval`` policy type and its checkpoint."""

    name: str
    policy: str
    checkpoint: str | None = None


def best_policy(checkpoint: Path) -> tuple[str, str | None, str]:
    """``(policy type, checkpoint or None, reason)``."""
    from lerobot.configs.policies import PreTrainedConfig

    if not (checkpoint / "config.json").is_file():
        return "demo_replay", None, f"no instant_policy checkpoint at {checkpoint}"
    if "instant_policy" not in PreTrainedConfig.get_known_choices():
        return "demo_replay", None, "the instant_policy policy is not installed in this version"
    return "instant_policy", str(checkpoint), f"checkpoint {checkpoint}"


def policies_to_run(choice: str, checkpoint: Path, replay_prior_checkpoint: Path) -> tuple[list[DemoPolicy], str]:
    """``([DemoPolicy, ...], reason)``: ``auto`` runs ``instant_policy`` from ``checkpoint`` (the paper's inference)
    and from ``replay_prior_checkpoint`` (the same network run from the per-object replay), each when it is there,
    beside ``demo_replay`` on the same scenes; any other choice runs that policy alone."""
    checkpoints = {"instant_policy": checkpoint, REPLAY_PRIOR: replay_prior_checkpoint}
    if choice in checkpoints:
        return [DemoPolicy(choice, "instant_policy", str(checkpoints[choice]))], "--policy"
    if choice != "auto":
        return [DemoPolicy(choice, choice)], "--policy"
    policies, reasons = [], []
    for name, path in checkpoints.items():
        policy, policy_path, reason = best_policy(path)
        reasons.append(f"{name}: {reason}")
        if policy == "instant_policy":
            policies.append(DemoPolicy(name, policy, policy_path))
    return policies + [DemoPolicy("demo_replay", "demo_replay")], "; ".join(reasons)


def run_demo(task: str, policies: list[DemoPolicy], episodes: int, batch_size: int, out: Path,
             report: Callable[[str], None] = print) -> dict[str, list[EpisodeOutcome]]:
    """Each policy on ``task`` for ``episodes`` episodes (one demonstration set, the same seeds for all); returns
    each policy's episodes in order, by its name."""
    outcomes: dict[str, list[EpisodeOutcome]] = {}
    for column in policies:
        settings = SuiteSettings(policy=column.policy, policy_path=column.checkpoint, out=out, episodes=episodes,
                                 demo_sets=1, batch_size=batch_size, run_name=column.name)
        settings.validate()
        outcomes[column.name] = episode_outcomes(run_task(settings, task), settings.eval_seed_of(0))
        report(f"task {task}: {column.name} succeeded in {success_percent(outcomes[column.name]):.0f}% of "
               f"{len(outcomes[column.name])} episodes")
    return outcomes


def test_split_figures(task: str, policies: list[DemoPolicy], table: Path = TEST_SPLIT_TABLE) -> dict[str, str]:
    """Each policy's ``successes/episodes`` on ``task`` in the test-split success ``table``
    (``lerobot-ip-eval-table``'s JSON), by the policy's demo name; a policy whose column or task the table lacks, or
    every policy when there is no table (an installed package without the repository's docs), is left out. Only the
    shipped checkpoints' columns are the table's: a policy run from another ``--checkpoint`` is left out too."""
    if not table.is_file():
        return {}
    rows = {(row["policy"], row["task"]): row for row in json.loads(table.read_text())["rows"]}
    shipped = {None, str(SHIPPED_CHECKPOINT), str(SHIPPED_REPLAY_PRIOR_CHECKPOINT)}
    figures = {}
    for column in policies:
        if column.checkpoint not in shipped:
            continue
        row = rows.get((TEST_SPLIT_COLUMNS.get(column.name), task))
        if row is not None:
            figures[column.name] = f"{row['successes']}/{row['episodes']}"
    return figures


def headline_failure(outcomes: dict[str, list[EpisodeOutcome]]) -> str | None:
    """The name of the demo's headline column when it succeeded in no episode, else ``None``: a demo that shows
    nothing. The headline is the recommended policy among those run (:data:`HEADLINE_ORDER`); the other columns are
    there to be compared with it, and one of them failing is what the demo's task shows (the paper's inference does
    12/30 on ``close_box``'s test split), not a failure of the demo."""
    headline = next((name for name in HEADLINE_ORDER if name in outcomes), None)
    if headline is None or any(episode.success for episode in outcomes[headline]):
        return None
    return headline
