"""Synthetic network inputs shared by the network's tests (``tests/model``) and mixed precision's (``tests/policy``):
a small config, a seeded network, and random scenes in world frames with the tensors ``InstantPolicyNetwork`` takes."""

import roma
import torch

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.model.instant_policy_network import DemoTensors, InstantPolicyNetwork
from lerobot_instant_policy.policy.features import contract_input_features

POINTS = 256  # the small encoder's first level samples 256 centroids


def tiny_config(**overrides) -> InstantPolicyConfig:
    """The policy's config, as the network takes it: small preset, hidden 32, clouds of POINTS points."""
    values = dict(hidden_dim=32, num_heads=4, pretrained_encoder=False, device="cpu",
                  input_features=contract_input_features(POINTS))
    return InstantPolicyConfig(**{**values, **overrides})


def seeded_network(seed: int = 0, **overrides) -> InstantPolicyNetwork:
    torch.manual_seed(seed)
    return InstantPolicyNetwork(tiny_config(**overrides)).eval()


def random_pose_tensors(shape: tuple, generator: torch.Generator, dtype, translation: float = 0.3,
                        angle: float = 3.0) -> torch.Tensor:
    """``(*shape, 4, 4)`` rigid poses from ``generator``: rotation vectors of std ``angle / 3`` rad, translations of
    std ``translation`` m (``synthetic_demos.random_poses`` draws numpy poses uniformly instead)."""
    T = torch.zeros(*shape, 4, 4, dtype=dtype)
    T[..., :3, :3] = roma.rotvec_to_rotmat(torch.randn(*shape, 3, generator=generator, dtype=dtype) * angle / 3)
    T[..., :3, 3] = torch.randn(*shape, 3, generator=generator, dtype=dtype) * translation
    T[..., 3, 3] = 1.0
    return T


def random_scenes(batch=2, num_demos=2, length=3, seed=0, dtype=torch.float32, points=POINTS, horizon=8) -> dict:
    """Synthetic scenes: random object-like blobs in world frames, EE poses near them, small relative actions."""
    g = torch.Generator().manual_seed(seed)

    def blob(*shape):
        return torch.randn(*shape, points, 3, generator=g, dtype=dtype) * 0.05

    return dict(
        demo_points_world=blob(batch, num_demos, length) + torch.tensor([0.5, 0.0, 0.1], dtype=dtype),
        demo_T_world_ee=random_pose_tensors((batch, num_demos, length), g, dtype),
        demo_gripper=torch.randint(0, 2, (batch, num_demos, length), generator=g).to(dtype),
        points_world=blob(batch) + torch.tensor([0.5, 0.0, 0.1], dtype=dtype),
        T_world_ee=random_pose_tensors((batch,), g, dtype),
        gripper=torch.randint(0, 2, (batch,), generator=g).to(dtype),
        T_ee_actions=random_pose_tensors((batch, horizon), g, dtype, translation=0.01, angle=0.03),
        action_gripper=torch.randint(0, 2, (batch, horizon), generator=g).to(dtype),
    )


def demo_tensors(network, batch) -> DemoTensors:
    """The batch's demonstrations as the network reads them: each waypoint cloud encoded in its own EE frame (what
    the policy's ContextEncoder computes)."""
    positions, features = network.encode_observation(batch["demo_points_world"], batch["demo_T_world_ee"])
    return DemoTensors(batch["demo_T_world_ee"], batch["demo_gripper"], positions, features)


def encoded_context(network, batch, **kwargs):
    return network.encode_context(
        demo_tensors(network, batch), batch["points_world"], batch["T_world_ee"], batch["gripper"], **kwargs
    )
