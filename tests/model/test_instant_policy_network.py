"""Instant Policy network: presets, the five defects of the authors' code, SE(3) invariance, context reuse,
variable context size, learning, and input errors."""

import dataclasses
from pathlib import Path

import pytest
import torch
from network_inputs import (
    demo_tensors,
    encoded_context,
    random_pose_tensors,
    random_scenes,
    seeded_network,
    tiny_config,
)
from safetensors.torch import load_file, save_file

import lerobot_instant_policy.model as model_package
from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.model.action_diffusion import points_in_action_frames
from lerobot_instant_policy.model.instant_policy_network import InstantPolicyNetwork

pytestmark = pytest.mark.usefixtures("single_torch_thread")


# ---------------------------------------------------------------- presets and sizes
def test_presets_have_the_documented_sizes():
    paper = InstantPolicyConfig(preset="paper", pretrained_encoder=False, device="cpu")
    assert (paper.hidden_dim, paper.num_heads, paper.hidden_dim // paper.num_heads) == (1024, 16, 64)
    assert paper.encoder_config.feature_dim == 512 and paper.encoder_config.num_nodes == 16
    network = InstantPolicyNetwork(paper)
    trainable = sum(p.numel() for p in network.parameters() if p.requires_grad)
    assert 90e6 < trainable < 150e6, trainable  # the paper's ≈118M
    assert all(not p.requires_grad for p in network.geometry_encoder.parameters())
    small = InstantPolicyNetwork(InstantPolicyConfig(preset="small", pretrained_encoder=False, device="cpu"))
    assert sum(p.numel() for p in small.parameters() if p.requires_grad) < 5e6


# ---------------------------------------------------------------- the authors' five defects
def test_defect_1_timestep_changes_the_network_output():
    network = seeded_network()
    batch = random_scenes()
    context = encoded_context(network, batch)
    gripper = 2 * batch["action_gripper"] - 1
    early = network.denoise(context, batch["T_ee_actions"], gripper, torch.tensor([5, 5]))
    late = network.denoise(context, batch["T_ee_actions"], gripper, torch.tensor([90, 90]))
    assert (early - late).abs().max() > 1e-3


def test_defect_2_ddim_renoises_between_steps():
    """Each DDIM iteration's next sample is the clean prediction re-noised to the next level (DDIM, η = 0), not the
    clean prediction itself; only the last iteration returns the clean prediction."""
    diffusion = seeded_network().diffusion
    flows = 0.3 * torch.randn(2, 8, 6, 7, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    seen = []  # (timestep, the sample the predictor was given, the clean value its prediction implies)

    def predict(T_noisy, gripper, timesteps):
        sample = torch.cat([diffusion.normalize_poses(T_noisy), gripper[..., None]], dim=-1)
        clean_poses = diffusion.normalize_poses(diffusion.predicted_clean_actions(T_noisy, flows[..., :6]))
        clean = torch.cat([clean_poses, flows[..., 6].mean(dim=-1).clamp(-1, 1)[..., None]], dim=-1)
        seen.append((int(timesteps[0]), sample, clean))
        return flows

    result = diffusion.sample(predict, 2, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    assert [timestep for timestep, _, _ in seen] == [99, 74, 49, 24]
    alphas = diffusion.inference_scheduler.alphas_cumprod.double()
    for (t, sample, clean), (t_next, next_sample, _) in zip(seen, seen[1:]):
        a_t, a_next = alphas[t], alphas[t_next]
        noise = (sample - a_t.sqrt() * clean) / (1 - a_t).sqrt()
        expected = (a_next.sqrt() * clean + (1 - a_next).sqrt() * noise).clamp(-1, 1)
        torch.testing.assert_close(next_sample, expected)
        assert (next_sample - clean).abs().max() > 1e-2  # re-noised, not the clean prediction
    torch.testing.assert_close(result, seen[-1][2])


@pytest.mark.parametrize("strength, timesteps", [(0.25, [24]), (0.5, [49, 24]), (1.0, [99, 74, 49, 24])])
def test_denoising_from_a_guess_runs_the_last_steps_from_the_noised_guess(strength, timesteps):
    """SDEdit (replay_init_strength): the guess is noised to the first kept timestep with the seed's noise, only the
    last ⌈strength·K⌉ DDIM steps run, and a denoiser that predicts the guess returns it."""
    diffusion = seeded_network().diffusion
    batch = random_scenes(dtype=torch.float64)
    guess = diffusion.normalize(batch["T_ee_actions"], batch["action_gripper"])
    T_guess, guess_gripper = diffusion.unnormalize(guess)
    seen = []

    def predict(T_noisy, gripper, step):
        seen.append((int(step[0]), torch.cat([diffusion.normalize_poses(T_noisy), gripper[..., None]], dim=-1)))
        flows = diffusion.flow_targets(T_guess, T_noisy)
        return torch.cat([flows, guess_gripper[..., None, None].expand(*flows.shape[:3], 1)], dim=-1)

    result = diffusion.sample(predict, 2, 4, generator=torch.Generator().manual_seed(3), dtype=torch.float64,
                              initial=guess, strength=strength)
    assert [step for step, _ in seen] == timesteps
    noise = torch.randn(2, 8, 7, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    torch.testing.assert_close(seen[0][1], diffusion.add_noise(guess, noise, torch.tensor([timesteps[0]] * 2)))
    torch.testing.assert_close(result, guess)


def test_bad_guesses_and_strengths_are_refused():
    diffusion = seeded_network().diffusion
    with pytest.raises(ValueError, match=r"strength must lie in \(0, 1\]"):
        diffusion.sample(lambda *args: None, 2, 4, initial=torch.zeros(2, 8, 7), strength=0.0)
    with pytest.raises(ValueError, match=r"initial must have shape \(B, T, 7\)"):
        diffusion.sample(lambda *args: None, 2, 4, initial=torch.zeros(2, 4, 7), strength=0.5)


def test_defect_3_action_frame_transform_is_R_transpose_of_p_minus_t():
    g = torch.Generator().manual_seed(0)
    points = torch.randn(1, 5, 3, generator=g, dtype=torch.float64)
    T = random_pose_tensors((1, 2), g, torch.float64)
    R, t = T[0, 1, :3, :3], T[0, 1, :3, 3]
    result = points_in_action_frames(points, T)
    torch.testing.assert_close(result[0, 1], (points[0] - t) @ R)  # Rᵀ (p − t), row-vector form
    wrong = points[0] @ R - t  # the authors' Rᵀ p − t
    assert (result[0, 1] - wrong).abs().max() > 1e-2
    # Mapping back with T_EA recovers the points: p_E = R p_A + t.
    torch.testing.assert_close(result[0, 1] @ R.T + t, points[0])


def test_defect_4_action_step_0_and_current_gripper_nodes_have_distinct_embeddings():
    network = seeded_network()
    for open_state in (0.0, 1.0):
        current = network.observation_gripper_features(torch.tensor([open_state]))  # (1, K, H)
        action = network.action_gripper_features(torch.tensor([[2 * open_state - 1] * 8]), torch.tensor([0]))
        assert (current[0] - action[0, 0]).abs().max() > 1e-3
    observation = network.observation_keypoint_embedding.weight
    action = network.action_keypoint_embedding.weight
    assert observation.data_ptr() != action.data_ptr()
    # Training the action embedding of step 0 leaves the current-frame embedding alone.
    before = observation.detach().clone()
    network.action_gripper_features(torch.zeros(1, 8), torch.tensor([3])).sum().backward()
    assert observation.grad is None and action.grad[: len(network.config.gripper_keypoints)].abs().sum() > 0
    torch.testing.assert_close(observation, before)


def test_defect_5_no_pickle_weights_are_safetensors(tmp_path):
    """(The config is JSON: ``tests/test_instant_policy_config.py``.)"""
    network = seeded_network()
    save_file(network.state_dict(), tmp_path / "model.safetensors")
    other = seeded_network(seed=1)
    other.load_state_dict(load_file(tmp_path / "model.safetensors"), strict=True)
    batch = random_scenes()
    gripper = 2 * batch["action_gripper"] - 1
    timesteps = torch.tensor([10, 60])
    torch.testing.assert_close(
        other.denoise(encoded_context(other, batch), batch["T_ee_actions"], gripper, timesteps),
        network.denoise(encoded_context(network, batch), batch["T_ee_actions"], gripper, timesteps),
    )
    for source in Path(model_package.__file__).parent.glob("*.py"):
        text = source.read_text()
        assert "pickle" not in text and "torch.save" not in text and "torch.load" not in text, source


# ---------------------------------------------------------------- diffusion pieces
def test_exact_flows_recover_the_clean_actions_by_svd():
    network = seeded_network()
    batch = random_scenes(dtype=torch.float64)
    diffusion = network.diffusion
    clean = diffusion.normalize(batch["T_ee_actions"], batch["action_gripper"])
    T_clean, gripper = diffusion.unnormalize(clean)
    torch.testing.assert_close(diffusion.normalize(T_clean, (gripper > 0).double()), clean)
    noisy = diffusion.add_noise(clean, torch.randn_like(clean), torch.tensor([50, 99]))
    T_noisy, _ = diffusion.unnormalize(noisy)
    flows = diffusion.flow_targets(T_clean, T_noisy)
    assert flows.abs().max() <= 1.0 + 1e-9
    torch.testing.assert_close(diffusion.predicted_clean_actions(T_noisy, flows), T_clean)


def test_actions_beyond_the_bounds_are_clamped():
    network = seeded_network()
    T = torch.eye(4).repeat(1, 8, 1, 1)
    T[0, :, 0, 3] = 0.5  # 50 cm, far beyond j cm
    sample = network.diffusion.normalize(T, torch.ones(1, 8))
    assert torch.equal(sample[0, :, 0], torch.ones(8))
    T_back, _ = network.diffusion.unnormalize(sample)
    torch.testing.assert_close(T_back[0, :, 0, 3], 0.01 * torch.arange(1, 9, dtype=torch.float32))


# ---------------------------------------------------------------- invariance, context reuse, context size
# The graphs a config builds: the paper's (actions re-encode the live cloud in their frames), the paper's with the
# encoded scene moved rigidly into the action frames, and the shipped default (actions see the scene through φ only).
GRAPHS = {
    "paper": dict(action_scene_graph=True, reencode_action_clouds=True, num_frequencies=10),
    "paper_rigid_scene": dict(action_scene_graph=True, reencode_action_clouds=False),
    "shipped": {},
}


@pytest.mark.parametrize("graph", list(GRAPHS))
def test_moving_the_whole_world_leaves_the_relative_actions_unchanged(graph):
    network = seeded_network(**GRAPHS[graph]).double()
    batch = random_scenes(dtype=torch.float64, seed=3)
    moved = dict(batch)
    world = random_pose_tensors((), torch.Generator().manual_seed(7), torch.float64, translation=1.0, angle=3.0)
    moved["demo_points_world"] = batch["demo_points_world"] @ world[:3, :3].T + world[:3, 3]
    moved["points_world"] = batch["points_world"] @ world[:3, :3].T + world[:3, 3]
    moved["demo_T_world_ee"] = world @ batch["demo_T_world_ee"]
    moved["T_world_ee"] = world @ batch["T_world_ee"]
    actions, gripper = network.sample_actions(encoded_context(network, batch), torch.Generator().manual_seed(1))
    moved_actions, moved_gripper = network.sample_actions(encoded_context(network, moved),
                                                          torch.Generator().manual_seed(1))
    torch.testing.assert_close(moved_actions, actions, atol=1e-8, rtol=1e-8)
    assert torch.equal(moved_gripper, gripper)
    # The prediction does depend on the scene: moving only the live cloud changes it.
    shifted = dict(batch, points_world=batch["points_world"] + torch.tensor([0.05, 0.0, 0.0], dtype=torch.float64))
    shifted_actions, _ = network.sample_actions(encoded_context(network, shifted), torch.Generator().manual_seed(1))
    assert (shifted_actions - actions).abs().max() > 1e-6


def _count_calls(module: torch.nn.Module) -> list:
    """Calls of ``module`` (its forward, or the dense path of a graph transformer)."""
    calls = []
    module.register_forward_hook(lambda *_: calls.append(1))
    if hasattr(module, "forward_dense"):
        dense = module.forward_dense
        module.forward_dense = lambda *args, **kwargs: calls.append(1) or dense(*args, **kwargs)
    return calls


@pytest.mark.parametrize("graph", list(GRAPHS))
def test_context_is_computed_once_and_reused_by_every_denoising_step(graph):
    network = seeded_network(**GRAPHS[graph])
    context = encoded_context(network, random_scenes())
    context_calls = _count_calls(network.context_network)
    local_calls = _count_calls(network.local_network)
    encoder_calls = _count_calls(network.geometry_encoder)
    actions, gripper = network.sample_actions(context, torch.Generator().manual_seed(0), num_inference_steps=4)
    assert actions.shape == (2, 8, 4, 4) and gripper.shape == (2, 8)
    assert set(gripper.unique().tolist()) <= {0.0, 1.0}
    assert len(context_calls) == 0  # φ is not re-run
    # σ only on the action local graphs, once per step (never in the shipped graph, where actions have none)
    assert len(local_calls) == (4 if network.config.action_scene_graph else 0)
    assert len(encoder_calls) == (4 if graph == "paper" else 0)
    rotations = actions[..., :3, :3]
    torch.testing.assert_close(rotations @ rotations.transpose(-1, -2), torch.eye(3).expand_as(rotations))



@pytest.mark.parametrize("strength", [1.0, 0.5])
def test_several_samples_per_prediction_are_the_mean_of_as_many_noise_draws(strength):
    """``num_samples`` S: each row is sampled S times as one batch of rows repeated S times (the same noise as
    sampling the repeated context directly, also from a replay guess), and the result is their mean pose per
    action; the gripper follows the samples wherever they agree; the same seed gives the same result."""
    from lerobot_instant_policy.geometry.rigid_torch import mean_rigid

    network = seeded_network()
    context = encoded_context(network, random_scenes())
    initial = None if strength == 1.0 else torch.rand(2, 8, 7, generator=torch.Generator().manual_seed(5)) * 2 - 1
    kwargs = dict(num_inference_steps=4, strength=strength)
    actions, gripper = network.sample_actions(context, torch.Generator().manual_seed(3), initial=initial,
                                              num_samples=4, **kwargs)
    samples, sample_gripper = network.sample_actions(
        context.repeat_rows(4), torch.Generator().manual_seed(3), **kwargs,
        initial=None if initial is None else initial.repeat_interleave(4, dim=0))
    assert actions.shape == (2, 8, 4, 4) and gripper.shape == (2, 8)
    torch.testing.assert_close(actions, mean_rigid(samples.unflatten(0, (2, 4)), dim=1))
    sample_gripper = sample_gripper.unflatten(0, (2, 4))
    agree = (sample_gripper == sample_gripper[:, :1]).all(dim=1)
    assert agree.any() and torch.equal(gripper[agree], sample_gripper[:, 0][agree])
    assert not torch.allclose(samples[0], samples[1])  # four different draws, not one
    again, _ = network.sample_actions(context, torch.Generator().manual_seed(3), initial=initial, num_samples=4,
                                      **kwargs)
    torch.testing.assert_close(again, actions)

@pytest.mark.parametrize("num_demos, length", [(1, 2), (1, 5), (3, 2), (5, 12)])
def test_variable_number_and_length_of_demonstrations(num_demos, length):
    network = seeded_network()
    context = encoded_context(network, random_scenes(batch=1, num_demos=num_demos, length=length))
    actions, gripper = network.sample_actions(context, torch.Generator().manual_seed(0), num_inference_steps=2)
    assert actions.shape == (1, 8, 4, 4) and torch.isfinite(actions).all() and gripper.shape == (1, 8)
    translation_bounds = 0.01 * torch.arange(1, 9) + 1e-6
    assert (actions[0, :, :3, 3].abs() <= translation_bounds[:, None]).all()


def test_cached_scene_nodes_and_waypoint_features_give_the_same_context():
    network = seeded_network()
    batch = random_scenes()
    joint = encoded_context(network, batch)

    # The live cloud's scene nodes given as encode_observation computes them (a frame-encoding cache) change nothing.
    scene = network.encode_observation(batch["points_world"], batch["T_world_ee"])
    from_cache = encoded_context(network, batch, scene_geometry=scene)
    torch.testing.assert_close(from_cache.current_gripper_features, joint.current_gripper_features)

    # σ on the demonstrations alone, handed in (a policy's per-task cache), gives the joint computation's context.
    demos = demo_tensors(network, batch)
    waypoints = network.encode_demo_waypoints(demos)
    assert waypoints.shape == (*batch["demo_gripper"].shape, 6, network.config.hidden_dim)
    from_waypoints = encoded_context(network, batch, demo_waypoint_features=waypoints)
    torch.testing.assert_close(from_waypoints.current_gripper_features, joint.current_gripper_features)
    with pytest.raises(ValueError, match="demo waypoint features"):
        encoded_context(network, batch, demo_waypoint_features=waypoints[:, :1])


def test_one_tasks_demonstrations_expand_to_a_batch_without_copies():
    network = seeded_network()
    batch = random_scenes(batch=1)
    demos = demo_tensors(network, batch)
    expanded = demos.expand(3)
    assert expanded.batch_size == 3 and expanded.scene_features.data_ptr() == demos.scene_features.data_ptr()
    with pytest.raises(ValueError, match="only a batch of one"):
        expanded.expand(6)


@pytest.mark.parametrize("action_scene_graph", [True, False])
def test_without_the_action_scene_graph_actions_see_the_scene_only_through_the_current_nodes(action_scene_graph):
    """The ablation ``action_scene_graph=False``: with φ's current nodes fixed, another scene changes nothing."""
    network = seeded_network(action_scene_graph=action_scene_graph, reencode_action_clouds=False)
    batch = random_scenes()
    context = encoded_context(network, batch)
    moved = dataclasses.replace(
        context, scene_positions_ee=context.scene_positions_ee.flip(0), scene_features=context.scene_features.flip(0)
    )
    timesteps = torch.tensor([10, 60])
    outputs = [network.denoise(c, batch["T_ee_actions"], batch["action_gripper"] * 2 - 1, timesteps)
               for c in (context, moved)]
    assert torch.equal(outputs[0], outputs[1]) != action_scene_graph


# ---------------------------------------------------------------- learning
def test_loss_falls_when_overfitting_a_tiny_batch():
    torch.manual_seed(0)
    network = InstantPolicyNetwork(tiny_config(preset="small", hidden_dim=None, num_heads=None,
                                                reencode_action_clouds=False)).train()
    batch = random_scenes(batch=2, num_demos=1, length=3, seed=5)
    demos = demo_tensors(network, batch)
    optimizer = torch.optim.AdamW([p for p in network.parameters() if p.requires_grad], lr=1e-3)
    generator = torch.Generator().manual_seed(0)
    losses = []
    for _ in range(100):
        context = network.encode_context(demos, batch["points_world"], batch["T_world_ee"], batch["gripper"])
        parts = network.training_loss(context, batch["T_ee_actions"], batch["action_gripper"], generator)
        optimizer.zero_grad()
        parts["loss"].backward()
        optimizer.step()
        losses.append(parts["loss"].item())
        assert set(parts) == {"loss", "translation", "rotation", "gripper"}
    first, last = sum(losses[:10]) / 10, sum(losses[-10:]) / 10
    assert last < 0.3 * first, (first, last)
    assert all(p.grad is None for p in network.geometry_encoder.parameters())
    assert not network.geometry_encoder.training


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "key, change, message",
    [
        ("points_world", lambda x: x.index_put_((torch.tensor(0),), torch.tensor(float("nan"))), "NaN"),
        ("T_world_ee", lambda x: x.index_put_((torch.tensor(0),), torch.tensor(float("nan"))), "NaN"),
        ("demo_T_world_ee", lambda x: x.index_put_((torch.tensor(1),), torch.tensor(float("inf"))), "NaN"),
        ("points_world", lambda x: x[:, :100], "num_points=256"),
        ("gripper", lambda x: x[:1], "gripper must have shape"),
    ],
)
def test_bad_inputs_raise_clear_errors(key, change, message):
    network = seeded_network()
    batch = random_scenes()
    batch[key] = change(batch[key].clone())
    with pytest.raises(ValueError, match=message):
        encoded_context(network, batch)


def test_bad_action_inputs_and_step_counts_raise():
    network = seeded_network()
    batch = random_scenes()
    context = encoded_context(network, batch)
    nan_actions = batch["T_ee_actions"].clone()
    nan_actions[0, 0, 0, 3] = float("nan")
    with pytest.raises(ValueError, match="T_ee_actions contains NaN"):
        network.training_loss(context, nan_actions, batch["action_gripper"])
    with pytest.raises(ValueError, match="T_ee_actions must have shape"):
        network.training_loss(context, batch["T_ee_actions"][:, :4], batch["action_gripper"])
    with pytest.raises(ValueError, match="num_inference_steps"):
        network.sample_actions(context, num_inference_steps=0)


def test_loss_weighs_a_gripper_cross_entropy_and_sampling_reads_its_logit():
    """``loss = translation + rotation + w · BCE(gripper logit)``; at sampling the logit's sign decides the command."""
    network = seeded_network(gripper_loss_weight=0.25)
    batch = random_scenes()
    context = encoded_context(network, batch)
    losses = network.training_loss(context, batch["T_ee_actions"], batch["action_gripper"],
                                   generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(losses["loss"], losses["translation"] + losses["rotation"] + 0.25 * losses["gripper"])
    last = network.gripper_head[-1]
    with torch.no_grad():
        last.weight.zero_()
        for bias, expected in ((20.0, 1.0), (-20.0, 0.0)):
            last.bias.fill_(bias)
            _, gripper = network.sample_actions(context, torch.Generator().manual_seed(0))
            assert torch.all(gripper == expected)
            confident = network.training_loss(context, batch["T_ee_actions"], torch.full_like(batch["action_gripper"],
                                                                                              expected))
            assert float(confident["gripper"]) < 1e-6  # a confident right logit costs nothing
