"""Speed of ``InstantPolicyPolicy``: milliseconds per control step and training samples per second.

Inputs are synthetic (random clouds of 2048 points, random EE poses): speed does not depend on what the points
show. The geometry encoder is randomly initialised when the preset has no shipped weights (``paper``), which
changes no timing. Each benchmark runs one setting (its options and config overrides); the repository's comparisons
of two settings in alternation are ``python -m workbench.cli.bench inference|train-step --compare-*``.
"""

from __future__ import annotations

import resource
import statistics
import time

import numpy as np
import torch

from ..configuration_instant_policy import InstantPolicyConfig
from ..contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY, poses_from_vectors_torch
from ..data.context_bank import ContextBank, EpisodeWaypoints
from ..data.demonstrations import Demonstration

#: Episodes in the context bank of :func:`bench_train_step`.
TRAIN_STEP_EPISODES = 8
#: The EE state of every context waypoint there: at the origin, identity orientation, gripper open.
_WAYPOINT_STATE = np.array([0, 0, 0, 0, 0, 0, 1, 1], np.float32)


def _config(preset: str, **overrides) -> InstantPolicyConfig:
    """The ``preset`` config on the GPU when there is one, without the pretrained encoder when its weights are
    missing (random weights time the same)."""
    config = InstantPolicyConfig(preset=preset, device="cuda" if torch.cuda.is_available() else "cpu", **overrides)
    if config.pretrained_encoder and not config.encoder_weights_path().is_file():
        config = InstantPolicyConfig(preset=preset, device=config.device, pretrained_encoder=False, **overrides)
    return config


def _use_layout(policy, dense_attention: bool) -> None:
    """Run ``policy``'s σ, φ and ψ in the dense layout (the network's) or, without ``dense_attention``, in the
    torch-geometric reference layout (the same weights and outputs)."""
    from ..model.sparse_graphs import SparseGraphs

    if not dense_attention:
        network = policy.network
        network.graphs = SparseGraphs(network.local_network, network.context_network, network.action_network,
                                      network.config.num_frequencies)


def _pose_rows(rng: np.random.Generator, count: int) -> np.ndarray:
    """``(count, 8)`` random EE poses near the table (xyz, unit quaternion xyzw with w ≥ 0, gripper)."""
    quats = rng.normal(size=(count, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    quats[quats[:, 3] < 0] *= -1
    positions = rng.uniform([0.3, -0.2, 0.05], [0.6, 0.2, 0.3], size=(count, 3))
    return np.concatenate([positions, quats, rng.integers(0, 2, (count, 1))], axis=1).astype(np.float32)


def _demo(rng: np.random.Generator, frames: int, points: int, task: str) -> Demonstration:
    """A demonstration of ``frames`` frames: one random cloud ``(points, 3)`` near the table in every frame, random
    EE states ``(frames, 8)``, actions equal to the states."""
    cloud = rng.uniform(-0.1, 0.1, size=(points, 3)).astype(np.float32) + np.array([0.5, 0.0, 0.05], np.float32)
    state = _pose_rows(rng, frames)
    return Demonstration(np.repeat(cloud[None], frames, axis=0), state, state.copy(), task)


def bench_inference(
    preset: str = "small",
    num_demos: int = 2,
    num_waypoints: int = 10,
    repeats: int = 5,
    policy_path: str | None = None,
    dense_attention: bool = True,
    **overrides,
) -> dict:
    """Median milliseconds of one ``predict_action_chunk`` (batch 1, demo context cached).

    A fresh ``preset`` policy with K=4, T=8, or the checkpoint at ``policy_path`` with its own K, T and
    ``reencode_action_clouds`` (``overrides`` still apply); ``dense_attention``: :func:`_use_layout`.
    """
    from ..modeling_instant_policy import InstantPolicyPolicy

    if policy_path is not None:
        from ..evaluation.checkpoints import load_policy

        device = "cuda" if torch.cuda.is_available() else "cpu"
        policy = load_policy(policy_path, device, num_demos=num_demos, num_waypoints=num_waypoints, **overrides)
        config, preset = policy.config, policy.config.preset
    else:
        config = _config(
            preset, num_demos=num_demos, num_waypoints=num_waypoints, horizon=8, inference_steps=4, **overrides
        )
        policy = InstantPolicyPolicy(config)
    _use_layout(policy, dense_attention)
    policy = policy.to(config.device).eval()
    rng = np.random.default_rng(0)
    policy.set_demonstrations([_demo(rng, 2 * num_waypoints, config.num_points, "bench") for _ in range(num_demos)])
    live = _demo(rng, 1, config.num_points, "bench")
    batch = {
        POINTCLOUD_KEY: torch.from_numpy(live.points_world).to(config.device),
        STATE_KEY: torch.from_numpy(live.state).to(config.device),
        "task": ["bench"],
    }
    start = time.perf_counter()
    policy.predict_action_chunk(batch)  # warm-up: compiles the layers where config.compile_inference
    warmup_s = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        policy.predict_action_chunk(batch)
        if config.device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return {
        "benchmark": "inference", "preset": preset, "checkpoint": policy_path, "device": config.device, "torch_threads": torch.get_num_threads(),
        "pretrained_encoder": config.pretrained_encoder, "reencode_action_clouds": config.reencode_action_clouds,
        "dense_attention": dense_attention, "compile_inference": config.compile_inference,
        "K": config.inference_steps, "N": num_demos, "L": num_waypoints, "T": config.horizon,
        "samples_per_prediction": config.samples_per_prediction,
        "points": config.num_points, "batch": 1,
        "parameters": sum(parameter.numel() for parameter in policy.parameters()),
        "ms_per_control_step": round(1000 * statistics.median(times), 1),
        "runs_ms": [round(1000 * value, 1) for value in times], "warmup_s": round(warmup_s, 1),
    }


def bench_train_step(
    preset: str = "small", batch_size: int = 8, num_demos: int = 2, repeats: int = 5, frame_cache: bool = True,
    use_amp: bool = False, fused_adamw: bool | None = None, dense_attention: bool = True, **overrides,
) -> dict:
    """Training samples per second of ``forward`` + ``backward`` + gradient clipping + optimizer step (N fixed), as
    one ``lerobot-train`` update with the policy's optimizer preset (``fused_adamw``: its ``fused`` option, ``None``
    for the preset's automatic choice), and the process's peak resident memory. With ``frame_cache`` every frame's
    scene nodes come from frame encodings computed beforehand, as ``lerobot-train`` reads them from beside its
    dataset; without it, the live clouds are encoded at every step and the context waypoints once (the context
    encoder's cache is warm before timing). ``use_amp`` runs ``forward`` under ``torch.autocast`` with the device's
    default dtype (bfloat16 on the CPU), as ``lerobot-train --policy.use_amp=true`` does where the config keeps it
    (on a CPU without fast bfloat16 kernels the config turns it off; the bench still measures it).
    ``dense_attention``: :func:`_use_layout`."""
    from ..modeling_instant_policy import InstantPolicyPolicy

    config = _config(preset, min_demos=num_demos, max_demos=num_demos, **overrides)
    policy = InstantPolicyPolicy(config)
    _use_layout(policy, dense_attention)
    policy = policy.to(config.device).train()
    L, P, T = config.num_waypoints, config.num_points, config.horizon
    bank, batch = _training_inputs(np.random.default_rng(0), config, batch_size)
    encodings = _frame_encodings(policy, bank, batch) if frame_cache else None
    policy.set_training_bank(bank, frame_encodings=encodings)
    batch = {key: value.to(config.device) for key, value in batch.items()}
    optimizer_config = config.get_optimizer_preset()
    optimizer_config.fused = fused_adamw
    optimizer = optimizer_config.build(policy.get_optim_params())

    def step() -> None:  # lerobot-train's update_policy, without its accelerator
        with torch.autocast(torch.device(config.device).type, enabled=use_amp):
            loss, _ = policy.forward(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), optimizer_config.grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        if config.device == "cuda":
            torch.cuda.synchronize()

    start = time.perf_counter()
    step()  # warm-up: fills the context encoder's cache; compiles the layers where config.compile_model
    warmup_s = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        step()
        times.append(time.perf_counter() - start)
    return {
        "benchmark": "train-step", "preset": preset, "device": config.device, "torch_threads": torch.get_num_threads(),
        "pretrained_encoder": config.pretrained_encoder, "reencode_action_clouds": config.reencode_action_clouds,
        "dense_attention": dense_attention, "frame_cache": frame_cache, "use_amp": use_amp,
        "compile_model": config.compile_model,
        "action_scene_graph": config.action_scene_graph, "num_frequencies": config.num_frequencies,
        "fused_adamw": bool(optimizer.defaults["fused"]), "batch": batch_size, "N": num_demos,
        "L": L, "T": T, "points": P, "samples_per_s": round(batch_size / statistics.median(times), 2),
        "runs_s_per_step": [round(value, 3) for value in times], "warmup_s": round(warmup_s, 1),
        "peak_rss_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def _training_inputs(rng: np.random.Generator, config: InstantPolicyConfig, batch_size: int) -> tuple[ContextBank, dict]:
    """A context bank of :data:`TRAIN_STEP_EPISODES` episodes of ``L`` waypoints (random clouds ``(L, P, 3)``, EE at
    the origin, frames ``0 … E·L − 1``) and a training batch of ``batch_size`` rows after them, as ``lerobot-train``'s
    loader gives it: clouds ``(B, P, 3)``, states ``(B, 8)``, action chunks ``(B, T, 8)`` (the state, jittered by
    5 mm), episode and frame indices."""
    L, P, T, episodes = config.num_waypoints, config.num_points, config.horizon, TRAIN_STEP_EPISODES
    bank = ContextBank([
        EpisodeWaypoints(index, "bench", np.arange(L), rng.uniform(-0.1, 0.1, (L, P, 3)).astype(np.float32),
                         np.tile(np.eye(4, dtype=np.float32), (L, 1, 1)), np.ones(L, np.float32),
                         np.arange(index * L, (index + 1) * L))
        for index in range(episodes)
    ])
    state = _pose_rows(rng, batch_size)
    actions = np.repeat(state[:, None], T, axis=1)
    actions[..., :3] += rng.normal(0.0, 0.005, size=(batch_size, T, 3)).astype(np.float32)
    batch = {
        POINTCLOUD_KEY: torch.from_numpy(rng.uniform(-0.1, 0.1, (batch_size, P, 3)).astype(np.float32)),
        STATE_KEY: torch.from_numpy(state),
        ACTION_KEY: torch.from_numpy(actions),
        "episode_index": torch.from_numpy(rng.integers(0, episodes, batch_size)),
        "index": torch.arange(episodes * L, episodes * L + batch_size),
    }
    return bank, batch


def _frame_encodings(policy, bank: ContextBank, batch: dict):
    """The ``FrameEncodings`` of every frame of :func:`_training_inputs` (frames ``0 … E·L − 1``: the bank's
    waypoints; then the batch rows), encoded by ``policy``'s network as ``lerobot-train`` finds them beside its
    dataset."""
    from ..training.frame_encodings import FrameEncodings

    config = policy.config
    points = torch.cat([torch.from_numpy(bank.points_world.reshape(-1, config.num_points, 3)), batch[POINTCLOUD_KEY]])
    waypoint_states = np.tile(_WAYPOINT_STATE, (TRAIN_STEP_EPISODES * config.num_waypoints, 1))
    states = torch.cat([torch.from_numpy(waypoint_states), batch[STATE_KEY]])
    T_world_ee, _ = poses_from_vectors_torch(states.to(config.device))
    positions, features = policy.network.encode_observation(points.to(config.device), T_world_ee)
    return FrameEncodings(None, positions.cpu().numpy(), features.cpu().numpy())

