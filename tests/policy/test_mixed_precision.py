"""``--policy.use_amp`` (issue 12): under autocast only the network's layers run in bfloat16. Every pose, point and
edge attribute stays exactly what float32 gives, the loss and the sampled actions stay float32 and close to the
float32 ones, and training under autocast still learns."""

from __future__ import annotations

import pytest
import torch
from network_inputs import encoded_context, random_scenes, seeded_network, tiny_config

from lerobot_instant_policy.geometry.rigid_torch import compose, full_precision, invert_rigid, transform_points
from lerobot_instant_policy.model.action_diffusion import points_in_action_frames
from lerobot_instant_policy.model.dense_graphs import dense_transform_attr
from lerobot_instant_policy.model.instant_policy_network import InstantPolicyNetwork

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def _bf16():
    return torch.autocast("cpu", dtype=torch.bfloat16)


def test_geometry_is_exactly_float32_under_autocast():
    batch = random_scenes(batch=2, horizon=8, seed=1)
    T_world_ee, T_ee_actions, points = batch["T_world_ee"], batch["T_ee_actions"], batch["points_world"]
    keypoints = torch.randn(6, 3, generator=torch.Generator().manual_seed(2)) * 0.05

    def geometry():
        return (invert_rigid(T_world_ee), compose(T_world_ee[:, None], T_ee_actions),
                transform_points(invert_rigid(T_world_ee), points), points_in_action_frames(points, T_ee_actions),
                dense_transform_attr(T_ee_actions, T_ee_actions, keypoints, 10))

    reference = geometry()
    with _bf16():
        assert (torch.ones(2, 2) @ torch.ones(2, 2)).dtype == torch.bfloat16  # autocast is on here
        under_autocast = geometry()
        with full_precision():
            assert (torch.ones(2, 2) @ torch.ones(2, 2)).dtype == torch.float32
    for got, expected in zip(under_autocast, reference, strict=True):
        assert got.dtype == torch.float32
        assert torch.equal(got, expected)


def test_loss_and_sampled_actions_stay_float32_and_close_under_autocast():
    network = seeded_network(seed=3, reencode_action_clouds=False)
    batch = random_scenes(batch=3, seed=4)
    results = []
    for amp in (False, True):
        with _bf16() if amp else torch.autocast("cpu", enabled=False):
            context = encoded_context(network, batch)
            loss = network.training_loss(context, batch["T_ee_actions"], batch["action_gripper"],
                                         torch.Generator().manual_seed(5))
            T_ee_actions, gripper = network.sample_actions(context, generator=torch.Generator().manual_seed(6))
        results.append((loss, T_ee_actions, gripper))
    (loss_32, actions_32, _), (loss_16, actions_16, _) = results
    for value in (loss_16["loss"], loss_16["translation"], actions_16):
        assert value.dtype == torch.float32
    assert float(loss_16["loss"].detach()) == pytest.approx(float(loss_32["loss"].detach()), rel=0.05)
    # Action j is bounded by j cm per axis; bf16 layers move it by under 5% of that bound.
    bound = network.diffusion.translation_bound.float()[:, None]
    assert bool(((actions_16[..., :3, 3] - actions_32[..., :3, 3]).abs() <= 0.05 * bound).all())
    assert torch.allclose(actions_16[..., 3, :], actions_32[..., 3, :])


def test_training_under_autocast_lowers_the_loss():
    torch.manual_seed(0)
    network = InstantPolicyNetwork(tiny_config(hidden_dim=None, num_heads=None, reencode_action_clouds=False)).train()
    batch = random_scenes(batch=2, num_demos=1, length=3, points=256, seed=5)
    optimizer = torch.optim.AdamW([p for p in network.parameters() if p.requires_grad], lr=1e-3)
    generator = torch.Generator().manual_seed(0)
    losses = []
    for _ in range(30):  # the loss halves within 30 steps; an AVX2 CPU emulates bfloat16, slowly
        with _bf16():
            parts = network.training_loss(encoded_context(network, batch), batch["T_ee_actions"],
                                          batch["action_gripper"], generator)
        optimizer.zero_grad()
        parts["loss"].backward()
        optimizer.step()
        losses.append(parts["loss"].item())
    assert sum(losses[-10:]) < 0.5 * sum(losses[:10]), losses
    assert all(parameter.dtype == torch.float32 for parameter in network.parameters())
