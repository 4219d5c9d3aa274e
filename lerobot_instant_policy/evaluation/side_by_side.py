"""What ``make demo`` shows: per-episode success of several policies on the same scenes, side by side, and a
contact sheet (first and last frame of every episode and policy, framed green for success and red for failure).

Both read only what ``lerobot-eval`` wrote: ``eval_info.json`` (per-task ``metrics.successes`` in episode order)
and the episode videos ``videos/<task>_0/eval_episode_<i>.mp4`` it lists in ``overall.video_paths``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np

from .success_table import EVAL_INFO, load_eval_info

SUCCESS_COLOUR = "#1a9850"
FAILURE_COLOUR = "#d73027"


@dataclass
class EpisodeOutcome:
    """One evaluated episode: its seed, whether it succeeded, and its video (``None`` when none was rendered)."""

    seed: int
    success: bool
    video: Path | None


def episode_outcomes(output_dir: Path, eval_seed: int) -> list[EpisodeOutcome]:
    """The episodes of a one-task ``lerobot-eval`` run in ``output_dir``, in order (seeds ``eval_seed + i``)."""
    info_path = Path(output_dir) / EVAL_INFO
    if not info_path.is_file():
        raise FileNotFoundError(f"no {EVAL_INFO} in {output_dir}: did lerobot-eval finish?")
    info = load_eval_info(info_path)
    if len(info["per_task"]) != 1:
        raise ValueError(f"{info_path} holds {len(info['per_task'])} tasks; a demo summary needs exactly one")
    successes = [bool(success) for success in info["per_task"][0]["metrics"]["successes"]]
    videos = [Path(path) for path in info.get("overall", {}).get("video_paths", [])]
    return [
        EpisodeOutcome(eval_seed + index, success, videos[index] if index < len(videos) else None)
        for index, success in enumerate(successes)
    ]


def success_percent(episodes: list[EpisodeOutcome]) -> float:
    """The share of ``episodes`` that succeeded, in percent."""
    return 100.0 * sum(episode.success for episode in episodes) / len(episodes)


def summary_table(task: str, outcomes: dict[str, list[EpisodeOutcome]]) -> str:
    """A plain-text table: one row per episode (seed), one column per policy, then the success rates."""
    policies = list(outcomes)
    counts = {len(episodes) for episodes in outcomes.values()}
    if len(counts) != 1:
        raise ValueError(f"the policies ran different numbers of episodes: {sorted(counts)}")
    width = max(len("success"), *(len(policy) for policy in policies)) + 2
    lines = [f"task {task}: the same {counts.pop()} scenes for every policy", "episode  seed  " +
             "".join(policy.ljust(width) for policy in policies)]
    for index, row in enumerate(zip(*outcomes.values(), strict=True)):
        cells = "".join(("success" if episode.success else "fail").ljust(width) for episode in row)
        lines.append(f"{index:<7}  {row[0].seed:<4}  {cells}")
    rates = "".join(f"{success_percent(outcomes[policy]):.0f}%".ljust(width) for policy in policies)
    lines.append(f"{'success':<13}  {rates}")
    return "\n".join(lines)


def first_and_last_frames(video: Path) -> tuple[np.ndarray, np.ndarray]:
    """The first and last frame of ``video`` as ``(H, W, 3)`` uint8 RGB (decoded with PyAV, no FFmpeg install)."""
    first = last = None
    with av.open(str(video)) as container:
        for frame in container.decode(video=0):
            last = frame
            if first is None:
                first = frame.to_ndarray(format="rgb24")
    if first is None:
        raise ValueError(f"{video} holds no video frames")
    return first, last.to_ndarray(format="rgb24")


def draw_contact_sheet(task: str, outcomes: dict[str, list[EpisodeOutcome]], path: Path) -> Path:
    """One row per episode, two columns (start, end) per policy, each framed by its episode's outcome."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    policies = list(outcomes)
    rows = len(next(iter(outcomes.values())))
    figure, axes = plt.subplots(rows, 2 * len(policies), figsize=(3.2 * len(policies) * 2, 2.6 * rows + 0.6),
                                squeeze=False)
    for column, policy in enumerate(policies):
        for row, episode in enumerate(outcomes[policy]):
            frames = first_and_last_frames(episode.video) if episode.video is not None else (None, None)
            colour = SUCCESS_COLOUR if episode.success else FAILURE_COLOUR
            for offset, (label, frame) in enumerate(zip(("start", "end"), frames, strict=True)):
                axis = axes[row, 2 * column + offset]
                if frame is not None:
                    axis.imshow(frame)
                axis.set_xticks([])
                axis.set_yticks([])
                for spine in axis.spines.values():
                    spine.set_edgecolor(colour)
                    spine.set_linewidth(5)
                outcome = "success" if episode.success else "fail"
                axis.set_title(f"{policy} · seed {episode.seed} · {label}" + (f" · {outcome}" if offset else ""),
                               fontsize=8, color=colour if offset else "black")
    figure.suptitle(f"{task}: first and last frame of every episode (green: success, red: failure)")
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=80)
    plt.close(figure)
    return path
