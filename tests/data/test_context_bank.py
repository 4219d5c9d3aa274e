"""The context bank (docs/design.md §6): each episode's L waypoints read once from a demonstration dataset, context
sampling among the other episodes of a task, and clear errors for datasets it cannot use."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_demos import make_demonstration, object_pose, write_demo_dataset

from lerobot_instant_policy.contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.data.context_bank import ContextBank, waypoint_frames
from lerobot_instant_policy.data.demonstrations import DemonstrationError
from lerobot_instant_policy.data.lerobot_format import contract_features, create_dataset, read_episode, write_episode
from lerobot_instant_policy.geometry.se3 import pose_from_pos_quat

PSEUDO_REPO = "local/bank_pseudo"
SYNTHETIC_REPO = "local/bank_synthetic"
L = 10


@pytest.fixture(scope="module")
def pseudo_dataset(tmp_path_factory):
    """Pseudo-demonstrations from the generator: 2 tasks × 3 demonstrations, gripper faults included."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.cli.generate import main as generate_main

    out = tmp_path_factory.mktemp("bank") / "pseudo"
    args = ["--out", str(out), "--repo-id", PSEUDO_REPO, "--no-progress", "--num-tasks", "2", "--demos-per-task", "3"]
    assert generate_main([*args, "--seed", "3", "--workers", "1"]) == 0
    dataset = LeRobotDataset(PSEUDO_REPO, root=out)
    episodes = [read_episode(dataset, index) for index in range(dataset.meta.total_episodes)]
    return out, dataset.meta, episodes


@pytest.fixture(scope="module")
def pseudo_bank(pseudo_dataset):
    root, _, _ = pseudo_dataset
    return ContextBank.from_dataset(PSEUDO_REPO, root, L)


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory):
    """Synthetic demonstrations (12 frames each): lift × 3, push × 1."""
    root = tmp_path_factory.mktemp("bank") / "synthetic"
    episodes = [
        ("lift", object_pose(0.5, 0.0, 0.0)),
        ("lift", object_pose(0.45, 0.1, 20.0)),
        ("push", object_pose(0.55, -0.1, -40.0)),
        ("lift", object_pose(0.4, 0.15, 55.0)),
    ]
    write_demo_dataset(root, SYNTHETIC_REPO, episodes)
    return root


def commanded_gripper(episode: dict) -> np.ndarray:
    return np.concatenate([episode["state"][:1, 7], episode["action"][:-1, 7]])


def test_bank_holds_each_episodes_waypoint_frames(pseudo_dataset, pseudo_bank):
    _, _, episodes = pseudo_dataset
    bank = pseudo_bank
    assert len(bank) == 6 and bank.num_waypoints == L and bank.num_points == 2048
    assert bank.tasks == sorted({episode["task"] for episode in episodes})
    assert bank.points_world.dtype == bank.T_world_ee.dtype == bank.gripper_open.dtype == np.float32
    assert bank.episode_indices.tolist() == list(range(len(episodes)))
    for index, episode in enumerate(episodes):
        frames = bank.frame_indices[index]
        assert bank.task_of_row[index] == episode["task"] and len(frames) == L and frames[0] == 0
        assert frames[-1] == len(episode["state"]) - 1 and np.all(np.diff(frames) > 0)
        assert bank.points_world[index].shape == (L, 2048, 3)
        np.testing.assert_array_equal(bank.points_world[index], episode["points"][frames])
        for pose, state in zip(bank.T_world_ee[index], episode["state"][frames]):
            np.testing.assert_allclose(pose, pose_from_pos_quat(state[:3], state[3:7]), atol=1e-6)
        np.testing.assert_array_equal(bank.gripper_open[index], commanded_gripper(episode)[frames])


def test_waypoints_keep_gripper_changes_and_ignore_flipped_gripper_observations(pseudo_dataset, pseudo_bank):
    _, _, episodes = pseudo_dataset
    faults = 0
    for index, episode in enumerate(episodes):
        gripper = commanded_gripper(episode)
        changes = np.flatnonzero(gripper[1:] != gripper[:-1]) + 1
        assert len(changes) >= 1, "a pseudo-task has at least one gripper change"
        frames = set(pseudo_bank.frame_indices[index].tolist())
        assert set(changes.tolist()) | set((changes - 1).tolist()) <= frames
        faults += int((episode["state"][:, 7] != gripper).sum())
    assert faults > 0, "the generator flips observed gripper states on some frames; the bank must not see them"


def test_built_from_dataset_meta_like_from_the_root(pseudo_dataset, pseudo_bank):
    _, meta, _ = pseudo_dataset
    bank = ContextBank.from_dataset_meta(meta, L)
    np.testing.assert_array_equal(bank.frame_indices, pseudo_bank.frame_indices)
    np.testing.assert_array_equal(bank.points_world, pseudo_bank.points_world)
    subset = ContextBank.from_dataset(PSEUDO_REPO, meta.root, 4, episodes=[4, 1])
    assert subset.episode_indices.tolist() == [4, 1] and subset.num_waypoints == 4


def test_episodes_of_task_and_unknown_task(pseudo_bank):
    for task in pseudo_bank.tasks:
        episodes = pseudo_bank.episodes_of_task(task)
        assert len(episodes) == 3 and all(pseudo_bank.task_of_row[episode] == task for episode in episodes)
    with pytest.raises(DemonstrationError, match=r"no episode of task 'stack' in the context bank; it has tasks \["):
        pseudo_bank.episodes_of_task("stack")


def test_sample_context_draws_other_episodes_of_the_same_task(pseudo_bank):
    rng = np.random.default_rng(0)
    for episode in range(len(pseudo_bank)):
        task = pseudo_bank.task_of_row[episode]
        same_task = set(pseudo_bank.episodes_of_task(task).tolist()) - {episode}
        context = pseudo_bank.sample_context(episode, 2, rng)
        assert context.shape == (2,) and set(context.tolist()) == same_task  # 2 others: all of them, no repeats
        single = pseudo_bank.sample_context(episode, 1, rng)
        assert single[0] in same_task
    # a demonstration never repeats: N above the other episodes of the task is refused, and the bank says the cap
    assert pseudo_bank.other_episode_counts(np.array([[0, 5]])).tolist() == [[2, 2]]
    with pytest.raises(DemonstrationError, match=r"has 2 episodes besides episode 0 .* N=3 needs 3"):
        pseudo_bank.sample_context(0, 3, rng)
    again = pseudo_bank.sample_context(0, 2, np.random.default_rng(7))
    np.testing.assert_array_equal(again, pseudo_bank.sample_context(0, 2, np.random.default_rng(7)))
    with pytest.raises(DemonstrationError, match="num_demos must be at least 1"):
        pseudo_bank.sample_context(0, 0, rng)
    with pytest.raises(DemonstrationError, match=r"episode 99 is not in the context bank \(6 episodes\)"):
        pseudo_bank.sample_context(99, 2, rng)


def test_gather_indexes_like_the_episode_array(pseudo_bank):
    episodes = np.array([[0, 2], [5, 5], [3, 1]])
    arrays = pseudo_bank.gather(episodes)
    assert arrays.points_world.shape == (3, 2, L, 2048, 3)
    assert arrays.T_world_ee.shape == (3, 2, L, 4, 4) and arrays.gripper_open.shape == (3, 2, L)
    np.testing.assert_array_equal(arrays.points_world[2, 0], pseudo_bank.points_world[3])
    np.testing.assert_array_equal(arrays.gripper_open[1, 1], pseudo_bank.gripper_open[5])


def test_from_demonstrations_in_python(synthetic_root):
    demos = [make_demonstration(object_pose(0.5, 0.0, 10.0 * index), "lift", seed=index) for index in range(3)]
    bank = ContextBank.from_demonstrations(demos, 6)
    assert bank.episode_indices.tolist() == [0, 1, 2] and bank.tasks == ["lift"]
    np.testing.assert_array_equal(bank.points_world[1], demos[1].points_world[bank.frame_indices[1]])


def test_waypoint_frames_give_the_banks_rows(pseudo_dataset, pseudo_bank):
    """The public reduction is the bank's: the same frames, poses and commanded gripper states per episode."""
    _, _, episodes = pseudo_dataset
    for index, episode in enumerate(episodes):
        chosen, T_world_ee, gripper_open = waypoint_frames(episode["state"], episode["action"], L)
        np.testing.assert_array_equal(chosen, pseudo_bank.frame_indices[index])
        np.testing.assert_array_equal(T_world_ee, pseudo_bank.T_world_ee[index])
        np.testing.assert_array_equal(gripper_open, pseudo_bank.gripper_open[index])
        assert T_world_ee.dtype == gripper_open.dtype == np.float32
    with pytest.raises(DemonstrationError, match="the third one: a demonstration of"):
        waypoint_frames(episodes[0]["state"][:5], episodes[0]["action"][:5], L, where="the third one")


def test_a_task_with_a_single_episode_has_no_context(synthetic_root):
    bank = ContextBank.from_dataset(SYNTHETIC_REPO, synthetic_root, 6)
    assert bank.episodes_of_task("push").tolist() == [2]
    with pytest.raises(DemonstrationError, match="task 'push' has 0 episodes besides episode 2 in the context bank"):
        bank.sample_context(2, 1, np.random.default_rng(0))


def test_episodes_shorter_than_L_are_refused(synthetic_root):
    with pytest.raises(DemonstrationError, match=r"episode 0 of the dataset at .*: a demonstration of 12 frames cannot "
                       r"give 20 waypoints"):
        ContextBank.from_dataset(SYNTHETIC_REPO, synthetic_root, 20)
    with pytest.raises(DemonstrationError, match=r"episodes \[7\] are not in the dataset"):
        ContextBank.from_dataset(SYNTHETIC_REPO, synthetic_root, 6, episodes=[0, 7])


@pytest.mark.parametrize("missing", [POINTCLOUD_KEY, STATE_KEY])
def test_dataset_without_a_contract_key_names_it(tmp_path, missing):
    from lerobot.datasets import LeRobotDataset

    features = {key: value for key, value in contract_features(64).items() if key != missing}
    root = tmp_path / "dataset"
    dataset = LeRobotDataset.create(SYNTHETIC_REPO, fps=10, features=features, root=root, use_videos=False)
    for _ in range(3):
        dataset.add_frame({key: np.zeros(spec["shape"], dtype=spec["dtype"]) for key, spec in features.items()}
                          | {"task": "lift"})
    dataset.save_episode()
    dataset.finalize()
    with pytest.raises(DemonstrationError, match=f"missing key '{missing}'"):
        ContextBank.from_dataset(SYNTHETIC_REPO, root, 2)


def test_nan_in_a_demonstration_is_refused(tmp_path):
    demo = make_demonstration(object_pose(0.5, 0.0, 0.0), "lift", seed=0)
    state = demo.state.copy()
    state[4, 0] = np.nan
    root = tmp_path / "dataset"
    dataset = create_dataset(SYNTHETIC_REPO, root)
    write_episode(dataset, demo.points_world, state, demo.action, "lift")
    dataset.finalize()
    with pytest.raises(DemonstrationError, match=f"episode 0 of the dataset at .*: {STATE_KEY} or {ACTION_KEY} "
                       "contains NaN"):
        ContextBank.from_dataset(SYNTHETIC_REPO, root, 6)
