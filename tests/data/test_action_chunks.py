"""Training rows' action chunks read from the dataset's action table (issue 12): the same chunks, padding and loss as
LeRobot's delta timestamps give, and clear errors for tables and indices that cannot give them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from synthetic_demos import object_pose, write_demo_dataset

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import ACTION_KEY
from lerobot_instant_policy.data.action_chunks import ActionChunks
from lerobot_instant_policy.data.demonstrations import DemonstrationError
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.training.batches import training_targets

REPO = "local/ip_action_chunks"
HORIZON = 8


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    """The same three episodes (12 frames each) read as lerobot-train reads them (each row's own action) and with
    LeRobot's delta timestamps (8-step chunks, padded past each episode's end)."""
    from lerobot.datasets import LeRobotDataset

    root = tmp_path_factory.mktemp("ip_chunks") / "data"
    poses = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0), object_pose(0.4, 0.15, 55.0)]
    write_demo_dataset(root, REPO, [("lift", pose) for pose in poses])
    rows = LeRobotDataset(REPO, root=root)
    chunked = LeRobotDataset(REPO, root=root, delta_timestamps={ACTION_KEY: [step / 10 for step in range(HORIZON)]})
    return rows, chunked


def test_chunks_and_padding_are_lerobots_delta_timestamp_chunks(datasets):
    rows, chunked = datasets
    table = ActionChunks.from_dataset(REPO, rows.root)
    assert len(table) == rows.num_frames
    frames = np.arange(rows.num_frames)
    actions, is_pad = table.chunks(frames, HORIZON)
    assert actions.shape == (rows.num_frames, HORIZON, 8) and actions.dtype == np.float32
    for frame in frames:
        expected = chunked[int(frame)]
        np.testing.assert_array_equal(actions[frame], expected[ACTION_KEY].numpy())
        np.testing.assert_array_equal(is_pad[frame], expected[f"{ACTION_KEY}_is_pad"].numpy())
    assert is_pad.any() and not is_pad[0].any()  # the last frames of an episode hold its last action


def test_lerobot_train_rows_give_the_loss_of_delta_timestamp_chunks(datasets):
    rows, chunked = datasets
    frames = [0, 5, 11, 12, 30, 35]  # 11 and 35 are the last frames of their episodes: fully padded chunks
    losses = []
    for dataset in (rows, chunked):
        batch = next(iter(torch.utils.data.DataLoader(torch.utils.data.Subset(dataset, frames), batch_size=6)))
        torch.manual_seed(0)
        config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, max_demos=1)
        policy = InstantPolicyPolicy(config, dataset_meta=dataset.meta).train()
        targets = dataclasses.astuple(training_targets(batch, config.horizon, config.num_points, policy.training_data))
        losses.append((float(policy.forward(batch)[0].detach()), targets))
    assert tuple(batch[ACTION_KEY].shape) == (6, HORIZON, 8)  # the delta-timestamp batch, for contrast
    (loss_rows, targets_rows), (loss_chunked, targets_chunked) = losses
    for got, expected in zip(targets_rows, targets_chunked, strict=True):
        torch.testing.assert_close(got, expected)
    assert loss_rows == pytest.approx(loss_chunked, rel=1e-6)


def test_rows_without_chunks_need_the_dataset(datasets):
    rows, _ = datasets
    batch = next(iter(torch.utils.data.DataLoader(rows, batch_size=2)))
    policy = InstantPolicyPolicy(InstantPolicyConfig(device="cpu"))
    with pytest.raises(RuntimeError, match="dataset_meta"):
        policy.forward(batch)


def test_bad_tables_and_indices_are_refused():
    action = np.zeros((5, 8), np.float32)
    with pytest.raises(DemonstrationError, match="consecutive"):
        ActionChunks(np.array([0, 1, 2, 4, 5]), np.zeros(5), action)
    with pytest.raises(DemonstrationError, match="episode's frames"):
        ActionChunks(np.arange(5), np.array([0, 0, 1, 1, 0]), action)
    bad = action.copy()
    bad[2, 1] = np.nan
    with pytest.raises(DemonstrationError, match="NaN"):
        ActionChunks(np.arange(5), np.zeros(5), bad)
    table = ActionChunks(np.arange(10, 15), np.array([3, 3, 3, 4, 4]), np.arange(40, dtype=np.float32).reshape(5, 8))
    actions, is_pad = table.chunks([11, 13], 3)
    np.testing.assert_array_equal(actions[:, :, 0], [[8, 16, 16], [24, 32, 32]])
    np.testing.assert_array_equal(is_pad, [[False, False, True], [False, False, True]])
    with pytest.raises(IndexError, match="outside"):
        table.chunks([15], 3)
