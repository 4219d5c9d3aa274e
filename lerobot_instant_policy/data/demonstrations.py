"""Demonstrations of a task, read from a local LeRobotDataset in the data contract (DESIGN §4, §6).

Policies that learn from a few demonstrations at test time (``demo_replay``, ``instant_policy``) name a dataset
with ``demo_repo_id`` / ``demo_root`` / ``num_demos`` and use the episodes whose ``task`` is the env's task
string. ``load_demonstrations`` reads them offline (never from the Hub) and says clearly what is wrong when the
dataset does not fit; ``Demonstration`` objects can also be built directly in Python.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .lerobot_format import ACTION_KEY, POINTCLOUD_KEY, POSE_GRIPPER_NAMES, STATE_KEY, read_episode


class DemonstrationError(ValueError):
    """A demonstration dataset is missing, not in the data contract, or lacks episodes of the asked task."""


@dataclass(frozen=True)
class Demonstration:
    """One demonstration of ``task``.

    ``points_world (F, P, 3)``: segmented object points per frame, world frame, metres.
    ``state (F, 8)``: EE pose per frame, world frame (xyz, quaternion xyzw), then ``gripper_open`` (1 open, 0 closed).
    ``action (F, 8)``: commanded EE pose for the next step, same layout, last entry the gripper command.
    """

    points_world: np.ndarray
    state: np.ndarray
    action: np.ndarray
    task: str

    def __post_init__(self) -> None:
        points, state, action = self.points_world, self.state, self.action
        if points.ndim != 3 or points.shape[2] != 3 or points.shape[1] == 0:
            raise DemonstrationError(f"points_world must have shape (F, P, 3) with P > 0, got {points.shape}")
        if state.shape != (len(points), 8) or action.shape != (len(points), 8):
            raise DemonstrationError(
                f"state and action must have shape (F, 8) with F = {len(points)} frames, got {state.shape}, {action.shape}"
            )
        if len(points) == 0:
            raise DemonstrationError("a demonstration needs at least one frame")
        for name, array in (("points_world", points), ("state", state), ("action", action)):
            if not np.all(np.isfinite(array)):
                raise DemonstrationError(f"demonstration of {self.task!r}: {name} contains NaN or infinite values")

    @property
    def num_frames(self) -> int:
        return len(self.state)


def load_demonstrations(repo_id: str, root: str | Path, task: str, num_demos: int) -> list[Demonstration]:
    """The first ``num_demos`` episodes of ``task`` in the LeRobotDataset at ``root``, in episode order.

    Raises ``DemonstrationError`` when ``root`` holds no LeRobotDataset, when the dataset's features are not the
    contract's (naming the missing or wrong keys), when no episode has ``task`` (listing the dataset's tasks) and
    when it has fewer than ``num_demos`` episodes of it (saying how many).
    """
    if num_demos < 1:
        raise DemonstrationError(f"num_demos must be at least 1, got {num_demos}")
    dataset = open_demo_dataset(repo_id, root)
    episodes = [
        int(episode["episode_index"]) for episode in dataset.meta.episodes if task in list(episode["tasks"])
    ]
    if not episodes:
        known = sorted(str(name) for name in dataset.meta.tasks.index)
        raise DemonstrationError(
            f"no episode of task {task!r} in the demonstration dataset at {dataset.root}; it has tasks {known}"
        )
    if len(episodes) < num_demos:
        raise DemonstrationError(
            f"asked for {num_demos} demonstrations of task {task!r} but the dataset at {dataset.root} has only {len(episodes)}"
        )
    demonstrations = []
    for episode_index in episodes[:num_demos]:
        episode = read_episode(dataset, episode_index)
        demonstrations.append(
            Demonstration(
                points_world=episode["points"].astype(np.float32),
                state=episode["state"].astype(np.float32),
                action=episode["action"].astype(np.float32),
                task=task,
            )
        )
    return demonstrations


def demo_dataset_root(repo_id: str, root: str | Path | None) -> Path:
    """``root``, or LeRobot's local cache ``$HF_LEROBOT_HOME/<repo_id>`` when it is unset (never a download)."""
    if root:
        return Path(root)
    from lerobot.utils.constants import HF_LEROBOT_HOME

    return HF_LEROBOT_HOME / repo_id


def open_demo_dataset(repo_id: str, root: str | Path):
    """The LeRobotDataset at ``root`` (offline), checked to be in the data contract; ``DemonstrationError`` if not."""
    root = Path(root)
    if not (root / "meta" / "info.json").is_file():
        reason = "does not exist" if not root.exists() else "has no meta/info.json"
        raise DemonstrationError(f"demonstration dataset root {root} {reason}: expected a LeRobotDataset written there")

    from lerobot.datasets import LeRobotDataset

    dataset = LeRobotDataset(repo_id, root=root)
    check_contract_features(dataset.meta.features, root)
    return dataset


def check_contract_features(features: dict[str, dict], root: str | Path) -> None:
    """Raise ``DemonstrationError`` naming every way ``features`` (LeRobot dataset metadata) break DESIGN §4."""
    problems = []
    expected = {
        POINTCLOUD_KEY: ("(P, 3)", lambda shape: len(shape) == 2 and shape[1] == 3 and shape[0] > 0, None),
        STATE_KEY: ("(8,)", lambda shape: shape == (8,), POSE_GRIPPER_NAMES),
        ACTION_KEY: ("(8,)", lambda shape: shape == (8,), POSE_GRIPPER_NAMES),
    }
    for key, (shape_text, shape_ok, names) in expected.items():
        feature = features.get(key)
        if feature is None:
            problems.append(f"missing key {key!r}")
            continue
        shape = tuple(feature.get("shape", ()))
        if not shape_ok(shape):
            problems.append(f"{key!r} has shape {shape}, expected {shape_text}")
        if feature.get("dtype") != "float32":
            problems.append(f"{key!r} has dtype {feature.get('dtype')!r}, expected 'float32'")
        if names is not None and list(feature.get("names") or []) != names:
            problems.append(f"{key!r} has names {feature.get('names')}, expected {names}")
    if problems:
        raise DemonstrationError(
            f"the dataset at {root} is not in the demonstration format (DESIGN §4): " + "; ".join(problems)
        )
