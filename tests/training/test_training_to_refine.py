"""Training to refine (``InstantPolicyConfig.refine_fraction``): refined rows start from the noised replay prior, the
network learns to correct it, a row whose prior the stream left out keeps the paper's loss, the faithful path is
untouched with the fields off, and a batch without priors is refused by name."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import (
    ACTION_KEY,
    REPLAY_PRIOR_KEPT_KEY,
    REPLAY_PRIOR_KEY,
    STATE_KEY,
    poses_from_vectors_torch,
)
from lerobot_instant_policy.geometry.rigid_torch import compose, invert_rigid
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig
from lerobot_instant_policy.pseudo_demos.stream import PseudoTaskStream, StreamConfig
from lerobot_instant_policy.training.batches import encoded_context, refinement
from lerobot_instant_policy.training.stream_seam import stream_config_for
from lerobot_instant_policy.training.task_pool import EncoderSource, encode_task

SHIPPED = "lerobot_instant_policy/assets/checkpoints/instant_policy"


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread(single_torch_thread):
    yield


@pytest.fixture(scope="module")
def pooled():
    """Four encoded live frames of two fresh tasks, with their replay priors, as the pool batches them."""
    stream = PseudoTaskStream(StreamConfig(
        generation=GenerationConfig(seed=11), num_demos=2, num_waypoints=10, horizon=8, samples_per_task=2,
        tasks_per_render=2, surface_samples=1024, zbuffer_resolution=(160, 120), replay_priors=True))
    encoder = EncoderSource(InstantPolicyConfig(device="cpu").encoder_config, checkpoint=SHIPPED).build()
    tasks = [encode_task(task, encoder, 8) for task in stream.render_tasks([3, 4])]
    return torch.utils.data.default_collate([task.sample(frame) for task in tasks for frame in range(2)])


def shipped(**overrides) -> InstantPolicyPolicy:
    policy = InstantPolicyPolicy.from_pretrained(SHIPPED)
    if overrides:
        config = dataclasses.replace(policy.config, **overrides)
        refined = InstantPolicyPolicy(config, load_encoder_weights=False)
        refined.load_state_dict(policy.state_dict())
        policy = refined
    return policy.train()


def prior_in_ee_frame(policy: InstantPolicyPolicy, batch: dict) -> torch.Tensor:
    T_world_ee, _ = poses_from_vectors_torch(batch[STATE_KEY])
    T_world_planned, gripper = poses_from_vectors_torch(batch[REPLAY_PRIOR_KEY])
    return policy.network.diffusion.normalize(compose(invert_rigid(T_world_ee)[:, None], T_world_planned), gripper)


def test_the_faithful_path_is_unchanged_with_the_refinement_off(pooled):
    """Fields off (fraction 0, whatever the strength): the same loss with or without priors in the batch, the same
    draws, the same gradients and the same sampled actions as the shipped model."""
    faithful, off = shipped(), shipped(refine_fraction=0.0, refine_max_strength=0.1)
    without = {key: value for key, value in pooled.items() if key != REPLAY_PRIOR_KEY}
    torch.manual_seed(3)
    loss, parts = faithful.forward(without)
    torch.manual_seed(3)
    loss_off, parts_off = off.forward(pooled)
    assert torch.equal(loss, loss_off) and parts == parts_off and "refined" not in parts
    loss.backward()
    loss_off.backward()
    for a, b in zip(faithful.get_optim_params(), off.get_optim_params(), strict=True):
        assert torch.equal(a.grad, b.grad)


def test_refined_rows_start_from_the_noised_prior(pooled, monkeypatch):
    """Every row refined at timestep 0 (strength 0.01 of 100 steps): the network sees the prior, barely noised, and
    regresses towards the clean actions."""
    policy = shipped(refine_fraction=1.0, refine_max_strength=0.01)
    seen = {}

    def recording(context, T_noisy, gripper, timesteps):
        seen.update(T_noisy=T_noisy, timesteps=timesteps)
        return original(context, T_noisy, gripper, timesteps)

    original = policy.network.denoise
    monkeypatch.setattr(policy.network, "denoise", recording)
    _, parts = policy.forward(pooled)
    assert parts["refined"] == 1.0 and seen["timesteps"].tolist() == [0, 0, 0, 0]
    T_prior, _ = policy.network.diffusion.unnormalize(prior_in_ee_frame(policy, pooled))
    T_actions, _ = policy.network.diffusion.unnormalize(prior_in_ee_frame(
        policy, {**pooled, REPLAY_PRIOR_KEY: pooled[ACTION_KEY]}))
    to_prior = (seen["T_noisy"][..., :3, 3] - T_prior[..., :3, 3]).norm(dim=-1).mean()
    to_actions = (seen["T_noisy"][..., :3, 3] - T_actions[..., :3, 3]).norm(dim=-1).mean()
    assert to_prior < 2e-3 < to_actions  # metres: the prior, not the actions, is what was noised


def test_a_few_steps_of_training_to_refine_correct_the_prior(pooled):
    """On a fixed batch, training to refine makes one DDIM step from the noised prior land nearer the demonstrated
    actions than the prior itself, which the untrained refinement does not."""
    torch.manual_seed(0)
    policy = shipped(refine_fraction=1.0, refine_max_strength=0.25, replay_init_strength=0.25)
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)

    def errors() -> tuple[float, float]:
        policy.eval()
        with torch.no_grad():
            context = policy.network.encode_context(
                encoded_context(pooled, 2), None, poses_from_vectors_torch(pooled[STATE_KEY])[0],
                (pooled[STATE_KEY][:, 7] > 0.5).float(),
                scene_geometry=(pooled["observation.scene_positions"], pooled["observation.scene_features"]))
            T_refined, _ = policy.network.sample_actions(context, num_inference_steps=4,
                                                         generator=torch.Generator().manual_seed(1),
                                                         initial=prior_in_ee_frame(policy, pooled), strength=0.25)
        policy.train()
        target = prior_in_ee_frame(policy, {**pooled, REPLAY_PRIOR_KEY: pooled[ACTION_KEY]})
        prior = prior_in_ee_frame(policy, pooled)
        refined = policy.network.diffusion.normalize_poses(T_refined)
        return float((refined - target[..., :6]).abs().mean()), float((prior - target)[..., :6].abs().mean())

    before, prior_error = errors()
    for _ in range(60):
        loss, _ = policy.forward(pooled)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    after, _ = errors()
    assert after < 0.5 * prior_error and after < 0.5 * before, (before, after, prior_error)


def test_a_batch_without_usable_priors_is_refused_by_name(pooled):
    policy = shipped(refine_fraction=0.5)
    without = {key: value for key, value in pooled.items() if key != REPLAY_PRIOR_KEY}
    with pytest.raises(KeyError, match="refine_fraction=0.5 trains on replay priors.*lerobot-ip-train"):
        policy.forward(without)
    with pytest.raises(ValueError, match=r"must have shape \(B, horizon, 8\) = \(4, 8, 8\), got \(4, 7, 8\)"):
        policy.forward({**pooled, REPLAY_PRIOR_KEY: pooled[REPLAY_PRIOR_KEY][:, :7]})
    broken = pooled[REPLAY_PRIOR_KEY].clone()
    broken[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="contains NaN"):
        policy.forward({**pooled, REPLAY_PRIOR_KEY: broken})


def test_the_stream_plans_priors_as_the_policy_trains_and_runs_them():
    stream = StreamConfig(generation=GenerationConfig(seed=11))
    refined = stream_config_for(InstantPolicyConfig(device="cpu", preset="refined"), stream)
    faithful = stream_config_for(InstantPolicyConfig(device="cpu"), stream)
    anchored = stream_config_for(InstantPolicyConfig(device="cpu", preset="refined", replay_per_object=False,
                                                     replay_anchored=True), stream)
    assert (refined.replay_priors, refined.replay_plan) == (True, "per_object")
    assert (faithful.replay_priors, faithful.replay_plan) == (False, "whole")
    assert (anchored.replay_priors, anchored.replay_plan) == (True, "anchored")
    with pytest.raises(ValueError, match="not two"):
        InstantPolicyConfig(device="cpu", preset="refined", replay_anchored=True)
    assert np.isclose(InstantPolicyConfig(device="cpu", preset="refined").refine_fraction, 0.5)


def test_rows_whose_prior_the_stream_left_out_are_never_refined(pooled):
    """``observation.replay_prior_kept`` False (a wrong prior beyond the share kept): the row starts from noise even
    with every row refined."""
    policy = shipped(refine_fraction=1.0)
    kept = torch.tensor([True, False, True, False])
    _, refined_rows = refinement({**pooled, REPLAY_PRIOR_KEPT_KEY: kept}, poses_from_vectors_torch(
        pooled[STATE_KEY])[0], policy.config.refine_fraction, policy.config.horizon, policy.network.diffusion)
    assert refined_rows.tolist() == kept.tolist()
    _, parts = policy.forward({**pooled, REPLAY_PRIOR_KEPT_KEY: kept})
    assert parts["refined"] == 0.5
