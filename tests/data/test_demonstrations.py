"""The demonstration loader (``data.demonstrations``): the episodes of one task from a local LeRobotDataset in the
data contract, and a clear error for every way a demonstration dataset can be wrong."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_demos import NUM_FRAMES, make_demonstration, object_pose, write_demo_dataset

from lerobot_instant_policy.contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.data.demonstrations import Demonstration, DemonstrationError, load_demonstrations

REPO_ID = "local/demos"


@pytest.fixture(scope="module")
def demo_dataset(tmp_path_factory):
    """Episodes: lift, push, lift, lift (object at a different pose each time)."""
    root = tmp_path_factory.mktemp("demos") / "dataset"
    episodes = [
        ("lift", object_pose(0.5, 0.0, 0.0)),
        ("push", object_pose(0.45, 0.1, 20.0)),
        ("lift", object_pose(0.55, -0.1, -40.0)),
        ("lift", object_pose(0.4, 0.15, 55.0)),
    ]
    written = write_demo_dataset(root, REPO_ID, episodes)
    return root, written


def test_loads_the_task_episodes_in_order(demo_dataset):
    root, written = demo_dataset
    demos = load_demonstrations(REPO_ID, root, "lift", 3)
    assert [demo.task for demo in demos] == ["lift"] * 3
    for demo, expected in zip(demos, [written[0], written[2], written[3]]):
        assert demo.points_world.shape == (NUM_FRAMES, 2048, 3) and demo.points_world.dtype == np.float32
        np.testing.assert_array_equal(demo.points_world, expected.points_world)
        np.testing.assert_array_equal(demo.state, expected.state)
        np.testing.assert_array_equal(demo.action, expected.action)
    (push,) = load_demonstrations(REPO_ID, root, "push", 1)
    np.testing.assert_array_equal(push.action, written[1].action)


def test_takes_only_the_first_num_demos(demo_dataset):
    root, written = demo_dataset
    demos = load_demonstrations(REPO_ID, root, "lift", 2)
    assert len(demos) == 2
    np.testing.assert_array_equal(demos[1].action, written[2].action)


def test_unknown_task_lists_the_dataset_tasks(demo_dataset):
    root, _ = demo_dataset
    with pytest.raises(DemonstrationError, match=r"no episode of task 'open_drawer'.*\['lift', 'push'\]"):
        load_demonstrations(REPO_ID, root, "open_drawer", 1)


def test_too_few_episodes_says_how_many(demo_dataset):
    root, _ = demo_dataset
    with pytest.raises(DemonstrationError, match=r"asked for 5 demonstrations of task 'lift'.*has only 3"):
        load_demonstrations(REPO_ID, root, "lift", 5)
    with pytest.raises(DemonstrationError, match="num_demos must be at least 1"):
        load_demonstrations(REPO_ID, root, "lift", 0)


def test_missing_root_is_reported_without_a_hub_download(tmp_path):
    with pytest.raises(DemonstrationError, match="does not exist"):
        load_demonstrations(REPO_ID, tmp_path / "nowhere", "lift", 1)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DemonstrationError, match="has no meta/info.json"):
        load_demonstrations(REPO_ID, tmp_path / "empty", "lift", 1)


def write_dataset_with(root, features: dict) -> None:
    """A one-episode dataset with the given ``features`` (values: zeros of each feature's shape)."""
    from lerobot.datasets import LeRobotDataset

    dataset = LeRobotDataset.create(REPO_ID, fps=10, features=features, root=root, use_videos=False)
    for _ in range(2):
        dataset.add_frame({key: np.zeros(spec["shape"], dtype=spec["dtype"]) for key, spec in features.items()} | {"task": "lift"})
    dataset.save_episode()
    dataset.finalize()


POSE = {"dtype": "float32", "shape": (8,), "names": ["x", "y", "z", "qx", "qy", "qz", "qw", "gripper_open"]}


@pytest.mark.parametrize(
    ("features", "message"),
    [
        (
            {STATE_KEY: POSE, ACTION_KEY: POSE},
            "missing key 'observation.pointcloud'",
        ),
        (
            {POINTCLOUD_KEY: {"dtype": "float32", "shape": (64, 3), "names": None}, STATE_KEY: POSE,
             ACTION_KEY: {"dtype": "float32", "shape": (7,), "names": None}},
            r"'action' has shape \(7,\), expected \(8,\)",
        ),
        (
            {POINTCLOUD_KEY: {"dtype": "float32", "shape": (64, 3), "names": None},
             STATE_KEY: {"dtype": "float32", "shape": (8,), "names": [f"joint_{i}" for i in range(8)]}, ACTION_KEY: POSE},
            r"'observation.state' has names \['joint_0'.*expected \['x'",
        ),
        (
            {POINTCLOUD_KEY: {"dtype": "float32", "shape": (64, 2), "names": None}, STATE_KEY: POSE, ACTION_KEY: POSE},
            r"'observation.pointcloud' has shape \(64, 2\), expected \(P, 3\)",
        ),
    ],
    ids=["no_pointcloud", "short_action", "joint_names", "flat_cloud"],
)
def test_dataset_in_another_format_names_what_is_wrong(tmp_path, features, message):
    write_dataset_with(tmp_path / "other", features)
    with pytest.raises(DemonstrationError, match="not in the demonstration format") as error:
        load_demonstrations(REPO_ID, tmp_path / "other", "lift", 1)
    assert error.match(message)


def test_demonstration_checks_its_arrays():
    demo = make_demonstration(object_pose(0.5, 0.0, 0.0), "lift", seed=0)
    with pytest.raises(DemonstrationError, match=r"shape \(F, 8\)"):
        Demonstration(demo.points_world, demo.state[:-1], demo.action, "lift")
    with pytest.raises(DemonstrationError, match=r"\(F, P, 3\)"):
        Demonstration(demo.points_world[..., :2], demo.state, demo.action, "lift")
    action = demo.action.copy()
    action[3, 0] = np.nan
    with pytest.raises(DemonstrationError, match="action contains NaN"):
        Demonstration(demo.points_world, demo.state, action, "lift")
