"""``lerobot-ip-record-demos``: task list, docs/design.md §4 datasets of scripted demonstrations, clear errors."""

from __future__ import annotations

import json

import numpy as np

from lerobot_instant_policy.cli.record_demos import main
from lerobot_instant_policy.sim.task_api import task_names


def test_list_tasks(capsys):
    assert main(["--list-tasks"]) == 0
    assert capsys.readouterr().out.split() == task_names()


def test_records_a_dataset_of_the_contract(tmp_path, capsys):
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.data.lerobot_format import contract_features, read_episode

    out = tmp_path / "push_button"
    args = [
        "--task",
        "push_button",
        "--episodes",
        "2",
        "--out",
        str(out),
        "--repo-id",
        "local/push_button",
        "--seed",
        "5",
    ]
    assert main([*args, "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["episodes"] == 2 and summary["seeds"] == [5, 6]
    dataset = LeRobotDataset("local/push_button", root=out)
    assert dataset.fps == 10 and dataset.num_episodes == 2
    for key, feature in contract_features().items():
        assert dataset.features[key]["shape"] == feature["shape"] and dataset.features[key]["dtype"] == "float32"
    assert set(dataset.features) - set(contract_features()) <= {
        "timestamp",
        "frame_index",
        "episode_index",
        "index",
        "task_index",
    }
    episode = read_episode(dataset, 0)
    assert episode["task"] == "push_button"
    assert episode["points"].shape[1:] == (2048, 3) and episode["points"].dtype == np.float32
    # the state is the one before the action: the next state reaches the commanded pose (bounded steps track)
    np.testing.assert_allclose(episode["state"][1:, :3], episode["action"][:-1, :3], atol=0.004)
    assert np.all(np.linalg.norm(np.diff(episode["action"][:, :3], axis=0), axis=1) <= 0.01 + 1e-6)
    assert episode["action"][:, 7].min() == 0.0  # the gripper closes to press
    assert main(args) == 2
    assert "--overwrite" in capsys.readouterr().err


def test_unknown_task_is_a_clear_error(tmp_path, capsys):
    assert main(["--task", "fly", "--out", str(tmp_path / "x"), "--repo-id", "local/x"]) == 2
    assert "known tasks" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_check_prints_a_table(capsys):
    assert main(["--check", "--task", "push_button", "--episodes", "2", "--seed", "10", "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["task"] == "push_button" and row["scripted_success"] == 1.0 and row["idle_success"] == 0.0
