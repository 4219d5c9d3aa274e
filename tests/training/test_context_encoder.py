"""The one context path (issue 13): a bank of waypoint data → ``ContextEncoder`` → the network's ``DemoTensors``, the
same for a training dataset with its frame encodings, a bank that encodes its clouds, and demonstrations handed in at
inference; each episode encoded once; clear errors when the pieces do not fit."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from synthetic_demos import object_pose, write_demo_dataset

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.data.context_bank import ContextBank
from lerobot_instant_policy.data.demonstrations import load_demonstrations
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.training.context_encoder import ContextEncoder

pytestmark = pytest.mark.usefixtures("single_torch_thread")

REPO = "local/ip_context_encoder"
L = 6


@pytest.fixture(scope="module")
def dataset_root(tmp_path_factory):
    """One task, three synthetic demonstrations of 12 frames."""
    root = tmp_path_factory.mktemp("context_encoder") / "data"
    poses = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0), object_pose(0.4, 0.15, 55.0)]
    write_demo_dataset(root, REPO, [("lift", pose) for pose in poses])
    return root


@pytest.fixture(scope="module")
def policy(dataset_root):
    from lerobot.datasets import LeRobotDatasetMetadata

    torch.manual_seed(0)
    config = InstantPolicyConfig(device="cpu", num_waypoints=L, reencode_action_clouds=False, max_demos=2)
    return InstantPolicyPolicy(config, dataset_meta=LeRobotDatasetMetadata(REPO, root=dataset_root))


def _count_encoder_calls(network) -> list[int]:
    calls = []
    network.geometry_encoder.register_forward_hook(lambda module, args, output: calls.append(len(args[0])))
    return calls


def test_training_and_inference_take_the_same_path_to_the_same_tensors(policy, dataset_root):
    """The dataset's frame encodings, the bank's clouds encoded on demand, and the same episodes handed in as
    demonstrations (the inference path) give the same demonstrations to the network."""
    episodes = np.array([[2, 0], [1, 2]])
    from_cache = policy.training_data.context_encoder().demos(episodes, "cpu")
    bank_with_clouds = ContextBank.from_dataset(REPO, dataset_root, L)
    encoded = ContextEncoder(policy.network, bank_with_clouds).demos(episodes, "cpu")
    handed_in = ContextEncoder(
        policy.network, ContextBank.from_demonstrations(load_demonstrations(REPO, dataset_root, "lift", 3), L)
    ).demos(episodes, "cpu")
    for other in (encoded, handed_in):
        torch.testing.assert_close(other.T_world_ee, from_cache.T_world_ee)
        torch.testing.assert_close(other.gripper_open, from_cache.gripper_open)
        torch.testing.assert_close(other.scene_positions, from_cache.scene_positions, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(other.scene_features, from_cache.scene_features, rtol=1e-5, atol=1e-5)
    assert from_cache.scene_positions.shape == (2, 2, L, 16, 3) and from_cache.scene_features.dtype == torch.float32
    # The policy's inference context of episodes 0 and 1, handed in, is the training context of the same episodes.
    policy.set_demonstrations(load_demonstrations(REPO, dataset_root, "lift", 2))
    task_demos = policy.task_context("lift").demos
    training = policy.training_data.context_encoder().demos(np.array([[0, 1]]), "cpu")
    for name in ("T_world_ee", "gripper_open", "scene_positions", "scene_features"):
        torch.testing.assert_close(getattr(task_demos, name), getattr(training, name), rtol=1e-5, atol=1e-5)


def test_each_episode_is_encoded_once_and_again_after_clear(policy, dataset_root):
    encoder = ContextEncoder(policy.network, ContextBank.from_dataset(REPO, dataset_root, L))
    calls = _count_encoder_calls(policy.network)
    first = encoder.demos(np.array([[0, 1]]), "cpu")
    encoder.demos(np.array([[1, 0], [0, 1]]), "cpu")
    assert sum(calls) == 2 * L  # episodes 0 and 1, once each
    again = encoder.demos(np.array([[0, 1]]), "cpu")
    torch.testing.assert_close(again.scene_features, first.scene_features)
    encoder.clear()
    encoder.demos(np.array([[0]]), "cpu")
    assert sum(calls) == 3 * L


def test_pieces_that_do_not_fit_are_refused(policy, dataset_root):
    light = ContextBank.from_dataset(REPO, dataset_root, L, read_points=False)
    with pytest.raises(ValueError, match="read without its clouds"):
        ContextEncoder(policy.network, light)
    handed_in = ContextBank.from_demonstrations(load_demonstrations(REPO, dataset_root, "lift", 2), L)
    with pytest.raises(ValueError, match="from their dataset"):
        ContextEncoder(policy.network, handed_in, policy.training_data.context_encoder().frame_encodings)
    with pytest.raises(ValueError, match=r"shape \(B, N\)"):
        ContextEncoder(policy.network, handed_in).demos(np.array([0, 1]), "cpu")
