"""The context bank: every episode of a demonstration dataset reduced to its ``L`` waypoints (docs/design.md §6).

During training, each frame of an episode gets as context ``N`` *other* episodes of the same ``task`` (the
demonstrations of one pseudo-task). The bank is built once, from the dataset's metadata root or from
``Demonstration`` objects, and holds per episode only what the context graph needs: the waypoints' object points
(world frame), EE poses and gripper states, and the waypoint frames' dataset ``index``. It is pure data: it never
calls the model (the policy's ``ContextEncoder`` turns its waypoints into the network's tensors) and is never a
module buffer, so it stays out of ``model.safetensors``.

Gripper state of a waypoint: the state the demonstrator had commanded up to that frame (``action[t − 1]``'s
gripper entry; ``state[0]``'s at the first frame). On a clean demonstration this is the observed state; it stays
right on the frames whose observed gripper state the pseudo-demonstration generator flips on purpose
(docs/design.md §7), which would otherwise count as gripper changes.

Memory: ``L · P · 3`` float32 per episode (240 KiB at L = 10, P = 2048); a bank read with ``read_points=False`` (training from frame encodings) holds only the poses, gripper states and indices.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY, poses_from_vectors
from .demonstrations import Demonstration, DemonstrationError, open_demo_dataset
from .waypoints import StopCriterion, extract_waypoints


@dataclass(frozen=True)
class EpisodeWaypoints:
    """One episode's waypoints. ``frame_indices (L,)`` within the episode; ``points_world (L, P, 3)`` float32 object
    points, world frame (None: not read, when their encodings come from a frame-encoding cache); ``T_world_ee (L, 4, 4)`` float32 EE poses; ``gripper_open (L,)`` float32, 1 open, 0 closed;
    ``dataset_indices (L,)`` the waypoint frames' global ``index`` in their dataset (None: not from a dataset)."""

    episode_index: int
    task: str
    frame_indices: np.ndarray
    points_world: np.ndarray | None
    T_world_ee: np.ndarray
    gripper_open: np.ndarray
    dataset_indices: np.ndarray | None = None


@dataclass(frozen=True)
class ContextArrays:
    """Waypoints of several episodes, indexed like the episode array ``(...)`` they were gathered for:
    ``points_world (..., L, P, 3)`` (None for a bank read without clouds), ``T_world_ee (..., L, 4, 4)``,
    ``gripper_open (..., L)`` (float32, world frame)."""

    points_world: np.ndarray | None
    T_world_ee: np.ndarray
    gripper_open: np.ndarray


class ContextBank:
    """Waypoints of every episode of a demonstration dataset, grouped by task. Build it with ``from_dataset``,
    ``from_dataset_meta`` or ``from_demonstrations``."""

    def __init__(self, waypoints: Sequence[EpisodeWaypoints]):
        if not waypoints:
            raise DemonstrationError("a context bank needs at least one episode")
        shapes = {(None if item.points_world is None else item.points_world.shape, item.T_world_ee.shape,
                   item.gripper_open.shape) for item in waypoints}
        if len(shapes) != 1:
            raise DemonstrationError(f"every episode must have the same waypoint array shapes, got {sorted(shapes)}")
        self.episode_indices = np.array([item.episode_index for item in waypoints], dtype=np.int64)
        if len(set(self.episode_indices.tolist())) != len(waypoints):
            raise DemonstrationError("episode indices in a context bank must be unique")
        self.task_of_row = [item.task for item in waypoints]
        self.frame_indices = np.stack([item.frame_indices for item in waypoints])
        self.points_world = (
            None if waypoints[0].points_world is None
            else np.stack([item.points_world for item in waypoints]).astype(np.float32, copy=False)
        )
        self.T_world_ee = np.stack([item.T_world_ee for item in waypoints]).astype(np.float32, copy=False)
        self.gripper_open = np.stack([item.gripper_open for item in waypoints]).astype(np.float32, copy=False)
        self._dataset_indices = np.stack([
            np.full(len(item.frame_indices), -1, np.int64) if item.dataset_indices is None
            else np.asarray(item.dataset_indices, dtype=np.int64)
            for item in waypoints
        ])
        self._has_dataset_indices = bool((self._dataset_indices >= 0).all())
        self._row_of = {int(episode): row for row, episode in enumerate(self.episode_indices)}
        by_task: dict[str, list[int]] = {}
        for episode, task in zip(self.episode_indices.tolist(), self.task_of_row):
            by_task.setdefault(task, []).append(episode)
        self._episodes_of_task = {task: np.array(episodes, dtype=np.int64) for task, episodes in by_task.items()}
        self._context_task = {task: task for task in by_task}  # whose episodes a task's frames get as context

    @classmethod
    def from_dataset(
        cls,
        repo_id: str,
        root: str | Path,
        num_waypoints: int,
        episodes: Sequence[int] | None = None,
        stop: StopCriterion = StopCriterion(),
        read_points: bool = True,
    ) -> ContextBank:
        """The bank of the LeRobotDataset at ``root`` (read offline), all episodes or only ``episodes``.

        Reads every frame's EE state and action, extracts the waypoints, then reads the point clouds of the
        waypoint frames only (not at all with ``read_points=False``: a bank of poses, gripper states and frame
        indices, for training from a frame-encoding cache; ``L · P · 3`` floats less per episode). ``DemonstrationError`` names what is wrong with a dataset outside the data contract
        (a missing ``observation.pointcloud`` or ``observation.state``, …), unknown episodes, an episode with
        fewer frames than ``num_waypoints``, and NaN or infinite values in the frames it reads.
        """
        dataset = open_demo_dataset(repo_id, root)
        meta_episodes = dataset.meta.episodes
        known = [int(index) for index in meta_episodes["episode_index"]]
        wanted = known if episodes is None else [int(index) for index in episodes]
        missing = sorted(set(wanted) - set(known))
        if missing:
            raise DemonstrationError(
                f"episodes {missing} are not in the dataset at {dataset.root} ({len(known)} episodes)"
            )
        position = {episode: row for row, episode in enumerate(known)}
        frames = dataset.hf_dataset.with_format("numpy", columns=[STATE_KEY, ACTION_KEY])[:]
        plans = []
        for episode in wanted:
            row = meta_episodes[position[episode]]
            start, stop_index = int(row["dataset_from_index"]), int(row["dataset_to_index"])
            state, action = frames[STATE_KEY][start:stop_index], frames[ACTION_KEY][start:stop_index]
            where = f"episode {episode} of the dataset at {dataset.root}"
            chosen, T_world_ee, gripper_open = waypoint_frames(state, action, num_waypoints, stop, where)
            plans.append((episode, row["tasks"][0], chosen, start, T_world_ee, gripper_open))
        rows = np.concatenate([start + chosen for _, _, chosen, start, _, _ in plans])
        columns = [POINTCLOUD_KEY, "index"] if read_points else ["index"]
        selected = dataset.hf_dataset.select(rows).with_format("numpy", columns=columns)[:]
        points = (
            selected[POINTCLOUD_KEY].reshape(len(plans), num_waypoints, -1, 3) if read_points
            else [None] * len(plans)
        )
        dataset_indices = np.asarray(selected["index"], dtype=np.int64).reshape(len(plans), num_waypoints)
        waypoints = []
        for plan, episode_points, indices in zip(plans, points, dataset_indices):
            episode, task, chosen, _, T_world_ee, gripper_open = plan
            if episode_points is not None and not np.isfinite(episode_points).all():
                raise DemonstrationError(
                    f"episode {episode} of the dataset at {dataset.root}: {POINTCLOUD_KEY} contains NaN or "
                    "infinite values"
                )
            waypoints.append(
                EpisodeWaypoints(episode, str(task), chosen, episode_points, T_world_ee, gripper_open, indices)
            )
        return cls(waypoints)

    @classmethod
    def from_dataset_meta(
        cls, dataset_meta, num_waypoints: int, stop: StopCriterion = StopCriterion(), read_points: bool = True
    ) -> ContextBank:
        """The bank of the dataset a ``LeRobotDatasetMetadata`` describes (its ``repo_id`` and local ``root``)."""
        return cls.from_dataset(dataset_meta.repo_id, dataset_meta.root, num_waypoints, stop=stop, read_points=read_points)

    @classmethod
    def from_demonstrations(
        cls, demonstrations: Sequence[Demonstration], num_waypoints: int, stop: StopCriterion = StopCriterion()
    ) -> ContextBank:
        """The bank of demonstrations handed in from Python; episode ``i`` is ``demonstrations[i]``."""
        waypoints = []
        for index, demo in enumerate(demonstrations):
            where = f"demonstration {index} of task {demo.task!r}"
            chosen, T_world_ee, gripper_open = waypoint_frames(demo.state, demo.action, num_waypoints, stop, where)
            waypoints.append(
                EpisodeWaypoints(index, demo.task, chosen, demo.points_world[chosen], T_world_ee, gripper_open)
            )
        return cls(waypoints)

    def __len__(self) -> int:
        return len(self.episode_indices)

    @property
    def num_waypoints(self) -> int:
        return self.T_world_ee.shape[1]

    @property
    def num_points(self) -> int | None:
        """P of the waypoint clouds; None for a bank read without them."""
        return None if self.points_world is None else self.points_world.shape[2]

    @property
    def tasks(self) -> list[str]:
        return sorted(self._episodes_of_task)

    def episodes_of_task(self, task: str) -> np.ndarray:
        """Episode indices ``(E_task,)`` of ``task``; ``DemonstrationError`` listing the bank's tasks if none."""
        episodes = self._episodes_of_task.get(task)
        if episodes is None:
            raise DemonstrationError(f"no episode of task {task!r} in the context bank; it has tasks {self.tasks}")
        return episodes.copy()

    def with_swapped_contexts(self) -> ContextBank:
        """The same bank, except that the frames of every task get the episodes of the *next* task (in sorted task
        order, the last task the first's) as context: the context-swap reference of the learning measurements. It
        shares this bank's arrays."""
        tasks = self.tasks
        if len(tasks) < 2:
            raise DemonstrationError("a context swap needs at least 2 tasks in the bank")
        swapped = copy.copy(self)
        swapped._context_task = {task: tasks[(index + 1) % len(tasks)] for index, task in enumerate(tasks)}
        return swapped

    def _context_candidates(self, episode_index: int) -> tuple[str, np.ndarray]:
        task = self.task_of_row[self._row(episode_index)]
        candidates = self._episodes_of_task[self._context_task[task]]
        return task, candidates[candidates != episode_index]

    def other_episode_counts(self, episode_indices) -> np.ndarray:
        """How many other episodes each of ``episode_indices (...)`` has in its task: the largest N it can get."""
        indices = np.asarray(episode_indices, dtype=np.int64)
        counts = [len(self._context_candidates(int(episode))[1]) for episode in indices.reshape(-1)]
        return np.array(counts, dtype=np.int64).reshape(indices.shape)

    def sample_context(self, episode_index: int, num_demos: int, rng: np.random.Generator) -> np.ndarray:
        """``num_demos`` distinct episode indices ``(N,)`` of other episodes with ``episode_index``'s task, in random
        order. A demonstration never repeats in one context: ``DemonstrationError`` when the task has fewer than N
        other episodes (cap N with :meth:`other_episode_counts`)."""
        if num_demos < 1:
            raise DemonstrationError(f"num_demos must be at least 1, got {num_demos}")
        task, others = self._context_candidates(episode_index)
        if len(others) < num_demos:
            raise DemonstrationError(
                f"task {task!r} has {len(others)} episodes besides episode {episode_index} in the context bank, "
                f"a context of N={num_demos} needs {num_demos}: generate at least N + 1 demonstrations per task"
            )
        return rng.choice(others, size=num_demos, replace=False)

    def gather(self, episode_indices) -> ContextArrays:
        """The waypoints of ``episode_indices`` (an int array of any shape ``(...)``)."""
        rows = self._rows(episode_indices)
        points = None if self.points_world is None else self.points_world[rows]
        return ContextArrays(points, self.T_world_ee[rows], self.gripper_open[rows])

    @property
    def has_dataset_indices(self) -> bool:
        """Whether every episode was read from a dataset, so its waypoints have global frame indices."""
        return self._has_dataset_indices

    def dataset_indices(self, episode_indices) -> np.ndarray:
        """The waypoint frames' global dataset ``index`` ``(..., L)`` of ``episode_indices (...)``;
        ``DemonstrationError`` for episodes that were not read from a dataset."""
        indices = self._dataset_indices[self._rows(episode_indices)]
        if (indices < 0).any():
            raise DemonstrationError("these context episodes were handed in, not read from a dataset: no frame index")
        return indices

    def _row(self, episode_index: int) -> int:
        row = self._row_of.get(int(episode_index))
        if row is None:
            raise DemonstrationError(f"episode {episode_index} is not in the context bank ({len(self)} episodes)")
        return row

    def _rows(self, episode_indices) -> np.ndarray:
        indices = np.asarray(episode_indices, dtype=np.int64)
        if indices.size == 0:
            raise DemonstrationError("no episodes asked for")
        return np.vectorize(self._row, otypes=[np.int64])(indices)


def waypoint_frames(
    state: np.ndarray,
    action: np.ndarray,
    num_waypoints: int,
    stop: StopCriterion = StopCriterion(),
    where: str = "a demonstration",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A demonstration's ``L = num_waypoints`` waypoints, as the bank holds them.

    Args:
        state: ``(F, 8)`` the frames' EE states (world frame; xyz, quaternion xyzw, gripper_open).
        action: ``(F, 8)`` the frames' actions, same layout.
        stop: when the EE "nearly stops" (:class:`~.waypoints.StopCriterion`).
        where: names the demonstration in errors.

    Returns:
        ``chosen (L,)`` int64 frame indices (:func:`~.waypoints.extract_waypoints` on the EE poses and the commanded
        gripper states), ``T_world_ee (L, 4, 4)`` float32 the EE poses there, world frame, and ``gripper_open (L,)``
        float32 the commanded gripper states there (see the module docstring). ``DemonstrationError`` for NaN or
        infinite values, an invalid quaternion or fewer than ``L`` frames.
    """
    if not (np.isfinite(state).all() and np.isfinite(action).all()):
        raise DemonstrationError(f"{where}: {STATE_KEY} or {ACTION_KEY} contains NaN or infinite values")
    try:
        T_world_ee, _ = poses_from_vectors(state)
    except ValueError as error:
        raise DemonstrationError(f"{where}: {STATE_KEY} holds an invalid EE quaternion ({error})") from error
    gripper_open = np.concatenate([state[:1, 7], action[:-1, 7]]).astype(np.float64)
    try:
        chosen = extract_waypoints(T_world_ee, gripper_open, num_waypoints, stop)
    except ValueError as error:
        raise DemonstrationError(f"{where}: {error}") from error
    return chosen, T_world_ee[chosen].astype(np.float32), gripper_open[chosen].astype(np.float32)
