"""The language head's regression targets: the trained network's bottleneck at frames of demonstrations, with other
demonstrations of the same task in context.

For every task of a demonstration dataset (a LeRobotDataset in the data contract, docs/design.md §4, whose episodes of
one task share its task string) with at least N + 1 episodes, each episode in turn is the live one and the N episodes
after it (cyclically, in episode order) are its context. At ``frames_per_episode`` frames spread evenly over the live
episode (first and last included; all frames with None) the bottleneck is computed the way the policy computes it at a
control step: :meth:`~..modeling_instant_policy.InstantPolicyPolicy.set_demonstrations` (the context reduced to its
waypoints, σ on them once), :meth:`~..modeling_instant_policy.InstantPolicyPolicy.task_context`, then
:meth:`~..model.instant_policy_network.InstantPolicyNetwork.encode_context` on the live frames (the encoder on each
cloud in its own EE frame, σ on the current local graph, φ). Each frame keeps what the head reads of it: its scene
nodes in its EE frame, their encoder features and the gripper state.

On disk (:meth:`LanguageTargets.save`): ``targets.safetensors`` (the arrays) and ``targets.json`` (the task names and
``build``: how the targets were made, compared by :func:`cached_targets` before it reuses them).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from safetensors.numpy import load_file, save_file

from ..contract import poses_from_vectors_torch
from ..data.demonstrations import Demonstration, open_demo_dataset, read_demonstration
from ..language.language_head import network_fingerprint
from ..language.paraphrases import Paraphrases
from ..model.instant_policy_network import InstantPolicyNetwork
from .frame_encodings import frame_files_fingerprint

logger = logging.getLogger(__name__)

ARRAYS_FILE, META_FILE = "targets.safetensors", "targets.json"
ARRAY_NAMES = ("task_index", "episode_index", "frame_index", "scene_positions", "scene_features", "gripper_open",
               "bottleneck")


class DemonstrationPolicy(Protocol):
    """What the targets need of the policy (``InstantPolicyPolicy`` is one): its network, and its way from a task's
    demonstrations to the context a control step reads (``set_demonstrations``, then ``task_context``)."""

    network: InstantPolicyNetwork

    def parameters(self): ...

    def set_demonstrations(self, demonstrations: list[Demonstration], num_waypoints: int | None = None) -> None: ...

    def task_context(self, task: str): ...


class TargetsError(ValueError):
    """A dataset whose tasks cannot give targets (too few episodes, a task not asked for), or a bad targets file."""


@dataclass
class LanguageTargets:
    """``F`` frames, each with its task and the bottleneck the network computes there with demonstrations.

    Attributes:
        tasks: the task names; ``task_index`` refers to them.
        task_index: ``(F,)`` int64.
        episode_index: ``(F,)`` int64, the live episode in its dataset.
        frame_index: ``(F,)`` int64, the frame within it.
        scene_positions: ``(F, M, 3)`` float32, the frame's scene nodes in its own EE frame.
        scene_features: ``(F, M, D)`` float32, their encoder features.
        gripper_open: ``(F,)`` float32, 1 open, 0 closed.
        bottleneck: ``(F, G, H)`` float32, φ's output at the current gripper nodes with the context.
        build: how they were made (network fingerprint, N, frames per episode, dataset), JSON-ready.
    """

    tasks: list[str]
    task_index: np.ndarray
    episode_index: np.ndarray
    frame_index: np.ndarray
    scene_positions: np.ndarray
    scene_features: np.ndarray
    gripper_open: np.ndarray
    bottleneck: np.ndarray
    build: dict = field(default_factory=dict)

    def __post_init__(self):
        frames = len(self.task_index)
        for name in ARRAY_NAMES:
            if len(getattr(self, name)) != frames:
                raise TargetsError(f"every targets array needs {frames} rows, {name} has {len(getattr(self, name))}")
        if frames and not 0 <= int(self.task_index.min()) <= int(self.task_index.max()) < len(self.tasks):
            raise TargetsError(f"task_index must refer to the {len(self.tasks)} tasks")

    @property
    def num_frames(self) -> int:
        return len(self.task_index)

    def select(self, rows: np.ndarray) -> LanguageTargets:
        """The frames ``rows`` (indices or a boolean mask), with the same task list."""
        return LanguageTargets(self.tasks, *(getattr(self, name)[rows] for name in ARRAY_NAMES), build=self.build)

    def split_episodes(self, fraction: float) -> tuple[LanguageTargets, LanguageTargets]:
        """``(train, held out)``: of each task's live episodes (in episode order) the last ``round(fraction · n)``
        are held out, at most ``n − 1`` of them, so every task keeps one for training."""
        if not 0.0 <= fraction < 1.0:
            raise TargetsError(f"the held-out fraction must be in [0, 1), got {fraction}")
        held = np.zeros(self.num_frames, dtype=bool)
        for task in np.unique(self.task_index):
            rows = self.task_index == task
            episodes = np.unique(self.episode_index[rows])
            count = min(len(episodes) - 1, round(fraction * len(episodes)))
            held |= rows & np.isin(self.episode_index, episodes[len(episodes) - count:])
        return self.select(~held), self.select(held)

    @classmethod
    def concatenate(cls, parts: list[LanguageTargets]) -> LanguageTargets:
        """The frames of all ``parts`` (of one network), their task lists merged in order of first appearance."""
        if not parts:
            raise TargetsError("nothing to concatenate")
        tasks = list(dict.fromkeys(task for part in parts for task in part.tasks))
        position = {task: index for index, task in enumerate(tasks)}
        remapped = [np.array([position[task] for task in part.tasks], dtype=np.int64)[part.task_index]
                    for part in parts]
        arrays = {name: np.concatenate([getattr(part, name) for part in parts]) for name in ARRAY_NAMES[1:]}
        build = parts[0].build if len(parts) == 1 else {"parts": [part.build for part in parts]}
        return cls(tasks, np.concatenate(remapped), **arrays, build=build)

    def save(self, directory: str | Path) -> None:
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        arrays = {name: np.ascontiguousarray(getattr(self, name)) for name in ARRAY_NAMES}
        save_file(arrays, str(directory / ARRAYS_FILE))
        (directory / META_FILE).write_text(json.dumps({"tasks": self.tasks, "build": self.build}, indent=2) + "\n")

    @classmethod
    def load(cls, directory: str | Path) -> LanguageTargets:
        directory = Path(directory)
        if not (directory / ARRAYS_FILE).is_file() or not (directory / META_FILE).is_file():
            raise TargetsError(f"no language targets at {directory} (expected {ARRAYS_FILE} and {META_FILE})")
        meta = json.loads((directory / META_FILE).read_text())
        arrays = load_file(str(directory / ARRAYS_FILE))
        return cls(meta["tasks"], *(arrays[name] for name in ARRAY_NAMES), build=meta["build"])


def evenly_spaced_frames(num_frames: int, count: int | None) -> np.ndarray:
    """``count`` frame indices spread evenly over ``0 … num_frames − 1``, first and last included (all of them when
    ``count`` is None or at least ``num_frames``)."""
    if count is None or count >= num_frames:
        return np.arange(num_frames)
    if count < 1:
        raise TargetsError(f"frames per episode must be at least 1, got {count}")
    return np.unique(np.round(np.linspace(0, num_frames - 1, count)).astype(np.int64))


@torch.no_grad()
def task_targets(policy: DemonstrationPolicy, demonstrations: list[Demonstration], num_demos: int = 2,
                 frames_per_episode: int | None = None, episode_indices: list[int] | None = None,
                 batch_size: int = 64) -> LanguageTargets:
    """The targets of one task from its ``demonstrations`` (module docstring; at least ``num_demos + 1``), labelled
    with ``episode_indices`` (default ``0 … n − 1``). Hands each context to ``policy`` with
    ``set_demonstrations``, which replaces the task's demonstrations there."""
    tasks = {demo.task for demo in demonstrations}
    if len(tasks) != 1:
        raise TargetsError(f"demonstrations of one task are needed, got tasks {sorted(tasks)}")
    (task,) = tasks
    if len(demonstrations) < num_demos + 1:
        raise TargetsError(f"task {task!r} has {len(demonstrations)} demonstrations; {num_demos + 1} are needed "
                           f"(one live, {num_demos} in context)")
    episode_indices = list(range(len(demonstrations))) if episode_indices is None else list(episode_indices)
    network, device = policy.network, next(policy.parameters()).device
    rows: dict[str, list[np.ndarray]] = {name: [] for name in ARRAY_NAMES}
    for live_position, live in enumerate(demonstrations):
        context = [demonstrations[(live_position + offset) % len(demonstrations)] for offset in range(1, num_demos + 1)]
        policy.set_demonstrations(context)
        task_context = policy.task_context(task)
        frames = evenly_spaced_frames(live.num_frames, frames_per_episode)
        for start in range(0, len(frames), batch_size):
            chosen = frames[start:start + batch_size]
            points = torch.from_numpy(live.points_world[chosen]).to(device)
            T_world_ee, gripper_open = poses_from_vectors_torch(torch.from_numpy(live.state[chosen]).to(device))
            gripper = (gripper_open > 0.5).float()
            count = len(chosen)
            waypoint_features = task_context.waypoint_features
            encoded = network.encode_context(
                task_context.demos.expand(count), points, T_world_ee, gripper,
                demo_waypoint_features=waypoint_features.expand(count, *waypoint_features.shape[1:]),
            )
            rows["task_index"].append(np.zeros(count, dtype=np.int64))
            rows["episode_index"].append(np.full(count, episode_indices[live_position], dtype=np.int64))
            rows["frame_index"].append(chosen.astype(np.int64))
            rows["scene_positions"].append(encoded.scene_positions_ee.float().cpu().numpy())
            rows["scene_features"].append(encoded.scene_features.float().cpu().numpy())
            rows["gripper_open"].append(gripper.cpu().numpy())
            rows["bottleneck"].append(encoded.current_gripper_features.float().cpu().numpy())
    return LanguageTargets([task], *(np.concatenate(rows[name]) for name in ARRAY_NAMES))


def build_targets(policy: DemonstrationPolicy, root: str | Path, repo_id: str | None = None, num_demos: int = 2,
                  frames_per_episode: int | None = None, tasks: list[str] | None = None,
                  paraphrases: Paraphrases | None = None) -> LanguageTargets:
    """The targets of every task of the demonstration dataset at ``root`` (repo id default ``local/<root name>``),
    or of ``tasks``; ``paraphrases``, when given, must have sentences for each (checked before any frame is
    encoded). ``TargetsError`` names the tasks with fewer than ``num_demos + 1`` episodes."""
    root = Path(root)
    dataset = open_demo_dataset(repo_id or f"local/{root.name}", root)
    by_task: dict[str, list[int]] = {}
    for episode in dataset.meta.episodes:
        by_task.setdefault(str(episode["tasks"][0]), []).append(int(episode["episode_index"]))
    if tasks is not None:
        unknown = sorted(set(tasks) - set(by_task))
        if unknown:
            raise TargetsError(f"the dataset at {root} has no episodes of {unknown}; its tasks are {sorted(by_task)}")
        by_task = {task: by_task[task] for task in tasks}
    if paraphrases is not None:
        paraphrases.check_tasks(by_task)
    short = {task: len(episodes) for task, episodes in by_task.items() if len(episodes) < num_demos + 1}
    if short:
        raise TargetsError(f"every task needs {num_demos + 1} episodes (one live, {num_demos} in context); the dataset "
                           f"at {root} has fewer for {short}")
    parts = []
    for task, episodes in by_task.items():
        episodes = sorted(episodes)
        logger.info("language targets: task %r, %d episodes", task, len(episodes))
        demonstrations = [read_demonstration(dataset, episode, task) for episode in episodes]
        parts.append(task_targets(policy, demonstrations, num_demos, frames_per_episode, episodes))
    targets = LanguageTargets.concatenate(parts)
    targets.build = targets_build(policy, root, num_demos, frames_per_episode, list(by_task))
    return targets


def targets_build(policy: DemonstrationPolicy, root: Path, num_demos: int, frames_per_episode: int | None,
                  tasks: list[str]) -> dict:
    """What determines the targets of the dataset at ``root``: the network's weights, N, the frames read, the tasks
    and the dataset's files (:func:`~.frame_encodings.frame_files_fingerprint`)."""
    return {"network_fingerprint": network_fingerprint(policy.network), "num_demos": num_demos,
            "frames_per_episode": frames_per_episode, "tasks": tasks, "dataset_root": str(Path(root).resolve()),
            "dataset": frame_files_fingerprint(Path(root))}


def cached_targets(directory: str | Path, policy: DemonstrationPolicy, root: str | Path, repo_id: str | None = None,
                   num_demos: int = 2, frames_per_episode: int | None = None, tasks: list[str] | None = None,
                   paraphrases: Paraphrases | None = None) -> LanguageTargets:
    """:func:`build_targets`, stored at ``directory`` and read from there instead when what is stored was built the
    same way from the same files (:func:`targets_build`)."""
    directory = Path(directory)
    if (directory / META_FILE).is_file() and (directory / ARRAYS_FILE).is_file():
        stored = LanguageTargets.load(directory)
        wanted_tasks = tasks if tasks is not None else stored.build.get("tasks")
        if stored.build == targets_build(policy, Path(root), num_demos, frames_per_episode, wanted_tasks):
            if paraphrases is not None:
                paraphrases.check_tasks(stored.tasks)
            return stored
        logger.info("language targets at %s were built otherwise; building them again", directory)
    targets = build_targets(policy, root, repo_id, num_demos, frames_per_episode, tasks, paraphrases)
    targets.save(directory)
    return targets
