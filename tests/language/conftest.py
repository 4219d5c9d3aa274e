"""Fixtures of the language room's tests: the network blocked, the shipped checkpoint, the default text encoder, the
shipped paraphrases, a tiny demonstration dataset of two suite tasks and a synthetic targets set in which only the
words tell tasks apart."""

from __future__ import annotations

import socket
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from synthetic_demos import make_demonstration, object_pose

from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from lerobot_instant_policy.data.lerobot_format import create_dataset, write_episode
from lerobot_instant_policy.language.paraphrases import Paraphrases
from lerobot_instant_policy.language.text_encoder import make_text_encoder
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.training.language_targets import LanguageTargets

# Two tasks of the suite, each demonstrated on its own object (the synthetic approach-and-lift motion).
DATASET_TASKS = {"pick_and_lift": "pb/mug", "knock_over": "pb/duck"}
EPISODES_PER_TASK = 3
SYNTHETIC_TASKS = ["pick_and_lift", "knock_over", "open_drawer"]
SYNTHETIC_SCENES = 8


@pytest.fixture
def no_network(monkeypatch):
    """Every attempt to open a connection fails."""

    def refuse(*args, **kwargs):
        raise OSError("network access attempted during a test that forbids it")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket.socket, "connect_ex", refuse)


@pytest.fixture(scope="session")
def shipped_policy() -> InstantPolicyPolicy:
    return InstantPolicyPolicy.from_pretrained(SHIPPED_CHECKPOINT).eval()


@pytest.fixture(scope="session")
def wordllama():
    return make_text_encoder("wordllama")


@pytest.fixture(scope="session")
def paraphrases() -> Paraphrases:
    return Paraphrases.load()


@dataclass(frozen=True)
class DemoDataset:
    """A demonstration dataset written for the tests: its ``root`` (repo id ``local/demos``), its ``tasks`` in episode
    order and the episodes of each."""

    root: Path
    tasks: tuple[str, ...]
    episodes_per_task: int


@pytest.fixture(scope="session")
def demo_dataset(tmp_path_factory) -> DemoDataset:
    """A LeRobotDataset in the data contract: 3 episodes of 12 frames of each task of :data:`DATASET_TASKS`, the object
    moved between episodes."""
    root = tmp_path_factory.mktemp("language") / "demos"
    dataset = create_dataset("local/demos", root)
    for task_number, (task, object_id) in enumerate(DATASET_TASKS.items()):
        for episode in range(EPISODES_PER_TASK):
            pose = object_pose(0.45 + 0.05 * episode, -0.1 + 0.1 * episode, 20.0 * episode - 20.0)
            demo = make_demonstration(pose, task, seed=10 * task_number + episode, object_id=object_id)
            write_episode(dataset, demo.points_world, demo.state, demo.action, task)
    dataset.finalize()
    return DemoDataset(root, tuple(DATASET_TASKS), EPISODES_PER_TASK)


@pytest.fixture(scope="session")
def synthetic_targets() -> LanguageTargets:
    """:data:`SYNTHETIC_SCENES` random scenes (scene nodes within 10 cm of the EE, random encoder features), each seen
    under every task of :data:`SYNTHETIC_TASKS` with a target of the task's pattern plus the scene's, normalised per
    node as φ's LayerNorm output is: the same observation has a different bottleneck per task, so only the sentence
    can tell which."""
    rng = np.random.default_rng(0)
    scenes, tasks = SYNTHETIC_SCENES, len(SYNTHETIC_TASKS)
    positions = rng.uniform(-0.1, 0.1, (scenes, 16, 3)).astype(np.float32)
    features = rng.normal(size=(scenes, 16, 256)).astype(np.float32)
    gripper = rng.integers(0, 2, scenes).astype(np.float32)
    bottleneck = rng.normal(size=(1, tasks, 6, 128)) + 0.5 * rng.normal(size=(scenes, 1, 6, 128))
    bottleneck = (bottleneck - bottleneck.mean(-1, keepdims=True)) / bottleneck.std(-1, keepdims=True)
    task_index, scene = np.tile(np.arange(tasks), scenes), np.repeat(np.arange(scenes), tasks)
    return LanguageTargets(SYNTHETIC_TASKS, task_index, scene, np.zeros(len(scene), dtype=np.int64), positions[scene],
                           features[scene], gripper[scene], bottleneck[scene, task_index].astype(np.float32))
