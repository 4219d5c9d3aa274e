"""A picture of pseudo-demonstrations in the style of the paper's figure 4.

One row per pseudo-task, one column per demonstration: object point clouds at a few frames (lighter = earlier)
and the gripper path, coloured by the commanded gripper state (green open, red closed), with a cross at every
commanded gripper change.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data.lerobot_format import read_episode


def draw_preview(episodes: list[list[dict]], path: str | Path, frames_per_demo: int = 4) -> Path:
    """Save a PNG of ``episodes[task][demo]``: dicts of ``points (F, P, 3)``, ``state (F, 8)``, ``action (F, 8)``, ``task``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, cols = len(episodes), max(len(demos) for demos in episodes)
    figure = plt.figure(figsize=(4.2 * cols, 4.0 * rows))
    for row, demos in enumerate(episodes):
        for col, demo in enumerate(demos):
            axis = figure.add_subplot(rows, cols, row * cols + col + 1, projection="3d")
            _draw_demo(axis, demo, frames_per_demo)
            axis.set_title(f"{demo['task']} — demo {col + 1}", fontsize=9)
    figure.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=90)
    plt.close(figure)
    return path


def load_preview_episodes(dataset, num_tasks: int = 2, demos_per_task: int = 3) -> list[list[dict]]:
    """Pick the first ``num_tasks`` tasks of a LeRobotDataset and up to ``demos_per_task`` episodes of each."""
    by_task: dict[str, list[int]] = {}
    for index in range(dataset.meta.total_episodes):
        by_task.setdefault(dataset.meta.episodes[index]["tasks"][0], []).append(index)
    return [
        [read_episode(dataset, episode) for episode in indices[:demos_per_task]]
        for indices in list(by_task.values())[:num_tasks]
    ]


def _draw_demo(axis, demo: dict, frames_per_demo: int) -> None:
    points, state = demo["points"], demo["state"]
    frames = np.linspace(0, len(state) - 1, frames_per_demo).round().astype(int)
    for order, frame in enumerate(frames):
        shade = 0.25 + 0.6 * order / max(len(frames) - 1, 1)
        cloud = points[frame][:: max(1, len(points[frame]) // 600)]
        axis.scatter(*cloud.T, s=1, color=(0.1, 0.3, 0.8, shade))
    positions, gripper_open = state[:, :3], demo["action"][:, 7] > 0.5
    for start in range(len(positions) - 1):
        color = "tab:green" if gripper_open[start] else "tab:red"
        axis.plot(*positions[start : start + 2].T, color=color, linewidth=1.5)
    changes = np.flatnonzero(gripper_open[1:] != gripper_open[:-1]) + 1
    axis.scatter(*positions[changes].T, s=25, color="black", marker="x")
    axis.scatter(*positions[:1].T, s=25, color="tab:green", marker="o")
    everything = np.concatenate([points[frames].reshape(-1, 3), positions])
    low, high = everything.min(axis=0), everything.max(axis=0)
    center, half = (low + high) / 2, (high - low).max() / 2 + 0.01
    axis.set_xlim(center[0] - half, center[0] + half)
    axis.set_ylim(center[1] - half, center[1] + half)
    axis.set_zlim(max(center[2] - half, -0.01), center[2] + half)
    axis.set_xlabel("x")
    axis.set_ylabel("y")
    axis.tick_params(labelsize=6)
