"""The language head on the shipped network: shapes, what its output does and does not depend on, the context it gives
ψ, saving and loading, and clear refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from synthetic_demos import object_cloud, object_pose, random_poses

from lerobot_instant_policy.language.context import language_context
from lerobot_instant_policy.language.language_head import (
    HeadBinding,
    LanguageHead,
    LanguageHeadConfig,
    LanguageHeadError,
    current_local_graph,
)
from lerobot_instant_policy.model.instant_policy_network import InstantPolicyNetwork

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def head(shipped_policy, wordllama) -> LanguageHead:
    torch.manual_seed(0)
    return LanguageHead(LanguageHeadConfig(), HeadBinding.of(shipped_policy.network, wordllama)).eval()


@pytest.fixture(scope="module")
def scene(shipped_policy):
    """Two observations of a mug seen from a gripper above it: world-frame clouds ``(2, P, 3)``, EE poses
    ``(2, 4, 4)``, gripper states ``(2,)``."""
    clouds = np.stack([object_cloud(object_pose(0.5, 0.0, 10.0), seed=1),
                       object_cloud(object_pose(0.55, 0.1, -30.0), seed=2)])
    poses = np.stack([object_pose(0.5, 0.02, 0.0), object_pose(0.5, 0.1, 45.0)])
    poses[:, :3, :3] = poses[:, :3, :3] @ np.diag([1.0, -1.0, -1.0])  # pointing down
    poses[:, 2, 3] = [0.2, 0.12]
    return torch.from_numpy(clouds), torch.from_numpy(poses).float(), torch.tensor([1.0, 0.0])


def head_inputs(network, points_world, T_world_ee, gripper):
    positions, features = network.encode_observation(points_world, T_world_ee)
    return (positions, *current_local_graph(network, positions, features, gripper))


def test_the_head_predicts_a_bottleneck_per_row(shipped_policy, wordllama, head, scene):
    network = shipped_policy.network
    positions, scene_nodes, gripper_nodes = head_inputs(network, *scene)
    text = torch.from_numpy(wordllama.encode(["open the drawer", "press the button"]))
    with torch.no_grad():
        out = head(positions, scene_nodes, gripper_nodes, text)
        alone = head(positions[1:], scene_nodes[1:], gripper_nodes[1:], text[1:])
        other_sentence = head(positions, scene_nodes, gripper_nodes, text.flip(0))
    assert out.shape == (2, 6, 128) and out.dtype == torch.float32 and torch.isfinite(out).all()
    torch.testing.assert_close(alone[0], out[1], atol=1e-5, rtol=1e-5)  # rows do not see each other
    assert (other_sentence - out).abs().amax() > 1e-2  # the words change the prediction


def test_the_order_of_the_scene_nodes_does_not_matter(shipped_policy, wordllama, head, scene):
    positions, scene_nodes, gripper_nodes = head_inputs(shipped_policy.network, *scene)
    text = torch.from_numpy(wordllama.encode(["pick up the cube", "knock over the tall block"]))
    order = torch.randperm(positions.shape[1], generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(head(positions[:, order], scene_nodes[:, order], gripper_nodes, text),
                                   head(positions, scene_nodes, gripper_nodes, text), atol=1e-5, rtol=1e-5)


def test_moving_the_whole_world_changes_neither_the_bottleneck_nor_the_actions(shipped_policy, wordllama, head,
                                                                               scene):
    """Everything the head reads is in the current EE frame: a rigid move of the cloud and the EE pose together leaves
    the predicted bottleneck and ψ's actions in the EE frame (same DDIM noise) as they were."""
    network, (points_world, T_world_ee, gripper) = shipped_policy.network, scene
    text = torch.from_numpy(wordllama.encode(["put the cube on the plate", "close the box"]))
    move = torch.from_numpy(random_poses(1, seed=3, extent_m=1.0)[0]).float()
    moved_points = points_world @ move[:3, :3].T + move[:3, 3]
    contexts = [language_context(network, head, text, points, poses, gripper)
                for points, poses in [(points_world, T_world_ee), (moved_points, move @ T_world_ee)]]
    torch.testing.assert_close(contexts[1].scene_positions_ee, contexts[0].scene_positions_ee, atol=1e-5, rtol=0)
    torch.testing.assert_close(contexts[1].current_gripper_features, contexts[0].current_gripper_features,
                               atol=1e-4, rtol=0)  # measured 2e-6 (float32)
    actions = [network.sample_actions(context, generator=torch.Generator().manual_seed(0)) for context in contexts]
    assert actions[0][0].shape == (2, 8, 4, 4) and actions[0][1].shape == (2, 8)
    torch.testing.assert_close(actions[1][0], actions[0][0], atol=1e-5, rtol=0)
    torch.testing.assert_close(actions[1][1], actions[0][1])


def test_a_saved_head_loads_equal_and_checks_what_it_was_made_for(tmp_path, shipped_policy, wordllama, head, scene):
    head.save(tmp_path / "head")
    record = json.loads((tmp_path / "head" / "config.json").read_text())
    assert record["binding"]["text_encoder"] == "wordllama" and record["binding"]["hidden_dim"] == 128
    loaded = LanguageHead.load(tmp_path / "head")
    assert loaded.state_dict().keys() == head.state_dict().keys()
    assert all(torch.equal(loaded.state_dict()[name], value) for name, value in head.state_dict().items())
    inputs = head_inputs(shipped_policy.network, *scene)
    text = torch.from_numpy(wordllama.encode(["stack the blocks", "lift the lid off the pot"]))
    with torch.no_grad():
        assert torch.equal(loaded(*inputs, text), head(*inputs, text))
    loaded.check_binding(shipped_policy.network, wordllama)
    torch.manual_seed(1)
    with pytest.raises(LanguageHeadError, match="bottleneck of another network"):
        loaded.check_binding(InstantPolicyNetwork(shipped_policy.config), wordllama)
    (tmp_path / "head" / "model.safetensors").unlink()
    with pytest.raises(LanguageHeadError, match="model.safetensors is missing"):
        LanguageHead.load(tmp_path / "head")


def test_bad_inputs_are_refused_naming_them(shipped_policy, head, scene):
    positions, scene_nodes, gripper_nodes = head_inputs(shipped_policy.network, *scene)
    text = torch.zeros(2, 256) + 1 / 16
    with pytest.raises(LanguageHeadError, match=r"text must have shape \(2, 256\)"):
        head(positions, scene_nodes, gripper_nodes, text[:, :128])
    with pytest.raises(LanguageHeadError, match=r"scene_nodes must have shape \(2, 16, 128\)"):
        head(positions, scene_nodes[..., :64], gripper_nodes, text)
    with pytest.raises(LanguageHeadError, match=r"gripper_nodes must have shape \(2, 6, 128\)"):
        head(positions, scene_nodes, gripper_nodes[:1], text)
    with pytest.raises(LanguageHeadError, match="text contains NaN"):
        head(positions, scene_nodes, gripper_nodes, text * float("nan"))
    with pytest.raises(ValueError, match="points_world has 100 points per cloud"):
        language_context(shipped_policy.network, head, text, scene[0][:, :100], scene[1], scene[2])
    with pytest.raises(LanguageHeadError, match="temperature must be positive"):
        LanguageHeadConfig(temperature=0.0)
