"""Demonstrations of a task, read from a local LeRobotDataset in the data contract (docs/design.md §4, §6).

Policies that learn from a few demonstrations at test time (``demo_replay``, ``instant_policy``) name a dataset
with ``demo_repo_id`` / ``demo_root`` / ``num_demos`` and use the episodes whose ``task`` is the env's task
string. ``load_demonstrations`` reads them offline (never from the Hub) and says clearly what is wrong when the
dataset does not fit; ``Demonstration`` objects can also be built directly in Python.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..contract import ACTION_KEY, POINTCLOUD_KEY, POSE_GRIPPER_NAMES, POSE_GRIPPER_SHAPE, STATE_KEY
from .lerobot_format import read_episode


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
    return [read_demonstration(dataset, episode_index, task) for episode_index in episodes[:num_demos]]


def read_demonstration(dataset, episode_index: int, task: str) -> Demonstration:
    """Episode ``episode_index`` of the LeRobotDataset ``dataset`` (in the data contract) as a float32
    ``Demonstration`` of ``task``."""
    episode = read_episode(dataset, episode_index)
    return Demonstration(
        points_world=episode["points"].astype(np.float32),
        state=episode["state"].astype(np.float32),
        action=episode["action"].astype(np.float32),
        task=task,
    )


def episodes_by_task(dataset) -> list[tuple[str, list[int]]]:
    """Each task of ``dataset`` (:func:`open_demo_dataset`'s; an episode's first task string names it, as in the
    pseudo-demonstrations ``lerobot-ip-generate`` writes) with its episode indices in order, the tasks in the order
    of their first episode."""
    by_task: dict[str, list[int]] = {}
    for episode in dataset.meta.episodes:
        by_task.setdefault(str(episode["tasks"][0]), []).append(int(episode["episode_index"]))
    return sorted(((task, sorted(episodes)) for task, episodes in by_task.items()), key=lambda item: item[1][0])


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
    check_dataset_features(dataset.meta.features, root)
    return dataset


class DemonstrationSource:
    """Where a policy's evaluation demonstrations come from, per task: handed in from Python (``hand_in``), or read
    once from the LeRobotDataset ``repo_id`` at ``root`` (offline; ``None``: LeRobot's local cache) and kept.

    A configured dataset is opened at construction, so a wrong path or format fails before the first episode.
    ``policy`` names the policy in error messages.
    """

    def __init__(self, policy: str, repo_id: str | None, root: str | Path | None, num_demos: int):
        self.policy, self.repo_id, self.num_demos = policy, repo_id, num_demos
        self.root = demo_dataset_root(repo_id, root) if repo_id is not None else None
        self._by_task: dict[str, list[Demonstration]] = {}
        self._handed_in: list[str] = []
        self._dataset_tasks: list[str] = []
        if repo_id is not None:
            dataset = open_demo_dataset(repo_id, self.root)
            self._dataset_tasks = sorted(str(name) for name in dataset.meta.tasks.index)

    def hand_in(self, demonstrations: list[Demonstration]) -> str:
        """Use ``demonstrations`` (all of one task) for their task from now on; returns the task."""
        tasks = {demo.task for demo in demonstrations}
        if len(tasks) != 1:
            raise DemonstrationError(f"set_demonstrations takes demonstrations of one task, got tasks {sorted(tasks)}")
        task = tasks.pop()
        self._by_task[task] = list(demonstrations)
        self._handed_in = [*(name for name in self._handed_in if name != task), task]
        return task

    def get(self, task: str) -> list[Demonstration]:
        """The demonstrations of ``task``: handed in, or ``num_demos`` read from the dataset on first use."""
        if task not in self._by_task:
            if self.repo_id is None:
                raise DemonstrationError(
                    f"{self.policy} has no demonstrations of task {task!r}: set --policy.demo_repo_id and "
                    "--policy.demo_root to a LeRobotDataset of demonstrations, or call set_demonstrations()"
                )
            self._by_task[task] = load_demonstrations(self.repo_id, self.root, task, self.num_demos)
        return self._by_task[task]

    @property
    def tasks(self) -> list[str]:
        """The tasks whose demonstrations were handed in or read so far."""
        return list(self._by_task)

    @property
    def default_task(self) -> str | None:
        """The task of a batch that names none: the task handed in when demonstrations of one task were, else the
        configured dataset's task when it holds one; ``None`` where that leaves several or none."""
        candidates = self._handed_in or self._dataset_tasks
        return candidates[0] if len(candidates) == 1 else None

    def batch_tasks(self, tasks, batch_size: int) -> list[str]:
        """The task of every batch row (:func:`batch_task_names` with :attr:`default_task`)."""
        if self._handed_in:
            known = f"; demonstrations of the tasks {sorted(self._handed_in)} were handed in"
        elif self.repo_id is not None:
            known = f"; the demonstration dataset at {self.root} has the tasks {self._dataset_tasks}"
        else:
            known = ("; or give demonstrations of one task (set_demonstrations(), or --policy.demo_repo_id and "
                     "--policy.demo_root naming a dataset of one task)")
        return batch_task_names(tasks, batch_size, self.policy, self.default_task, known)


def batch_task_names(tasks, batch_size: int, policy: str, default_task: str | None, known: str = "") -> list[str]:
    """The task of every row of a batch: ``tasks`` is ``batch.get("task")`` (one string for all rows, or one per
    row); when it is missing every row gets ``default_task``, and without one a ``KeyError`` says what to pass
    (``known`` ends its message: the tasks the policy could have used)."""
    if tasks is None:
        if default_task is not None:
            return [default_task] * batch_size
        raise KeyError(f"{policy} needs the task of its batch rows: pass batch['task'], one task string for every row "
                       f"or a list of one per row (lerobot-eval passes the env's task){known}")
    tasks = [tasks] * batch_size if isinstance(tasks, str) else list(tasks)
    if len(tasks) != batch_size:
        raise ValueError(f"batch['task'] has {len(tasks)} entries for a batch of {batch_size}")
    return tasks


def check_dataset_features(features: dict[str, dict], root: str | Path) -> None:
    """Raise ``DemonstrationError`` naming every way ``features`` (LeRobot dataset metadata) break docs/design.md §4."""
    problems = []
    expected = {
        POINTCLOUD_KEY: ("(P, 3)", lambda shape: len(shape) == 2 and shape[1] == 3 and shape[0] > 0, None),
        STATE_KEY: (str(POSE_GRIPPER_SHAPE), lambda shape: shape == POSE_GRIPPER_SHAPE, POSE_GRIPPER_NAMES),
        ACTION_KEY: (str(POSE_GRIPPER_SHAPE), lambda shape: shape == POSE_GRIPPER_SHAPE, POSE_GRIPPER_NAMES),
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
            f"the dataset at {root} is not in the demonstration format (docs/design.md §4): " + "; ".join(problems)
        )
