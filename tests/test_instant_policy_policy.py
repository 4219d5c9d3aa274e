"""``InstantPolicyPolicy`` (issue 5, parts 6 and 8): relative actions that do not depend on where the world is,
learning on a tiny dataset, any N and L at inference, the action queue, clear errors for bad input, strict
checkpoints, the save/load round trip with processors, and ``push_to_hub`` against a stand-in for the Hub API."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from synthetic_demos import NUM_FRAMES, expected_actions, make_demonstration, object_pose, write_demo_dataset

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import (
    ACTION_KEY,
    CONTEXT_GRIPPER_OPEN_KEY,
    CONTEXT_ID_KEY,
    CONTEXT_POINTCLOUD_KEY,
    CONTEXT_T_WORLD_EE_KEY,
    POINTCLOUD_KEY,
    STATE_KEY,
    poses_from_vectors_torch,
)
from lerobot_instant_policy.data.demonstrations import Demonstration, DemonstrationError
from lerobot_instant_policy.geometry.se3 import make_pose, pose_from_pos_quat, pose_to_pos_quat, transform_points
from lerobot_instant_policy.modeling_instant_policy import (
    CheckpointMismatchError,
    InstantPolicyPolicy,
)
from lerobot_instant_policy.processor_instant_policy import make_instant_policy_pre_post_processors
from lerobot_instant_policy.training.batches import hold_padded

pytestmark = pytest.mark.usefixtures("single_torch_thread")

TASK = "lift"
REPO = "local/ip_policy_tiny"


def lift_demos(count: int = 3) -> list[Demonstration]:
    poses = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0), object_pose(0.4, 0.15, 55.0),
             object_pose(0.55, -0.1, -40.0)]
    return [make_demonstration(poses[index], TASK, seed=index) for index in range(count)]


def live_observation(frame: int = 2, batch: int = 1) -> dict:
    """The lift task's frame ``frame`` with the object at a pose no demonstration had."""
    demo = make_demonstration(object_pose(0.52, -0.05, 35.0), TASK, seed=11)
    return {
        POINTCLOUD_KEY: torch.from_numpy(demo.points_world[frame]).repeat(batch, 1, 1),
        STATE_KEY: torch.from_numpy(demo.state[frame]).repeat(batch, 1),
        "task": [TASK] * batch,
    }


def relative_actions(observation: dict, chunk: torch.Tensor) -> torch.Tensor:
    """``T_EA (B, T, 4, 4)`` of absolute actions ``chunk (B, T, 8)`` relative to the observed EE pose."""
    T_world_ee, _ = poses_from_vectors_torch(observation[STATE_KEY])
    T_world_actions, _ = poses_from_vectors_torch(chunk)
    return torch.linalg.inv(T_world_ee)[:, None] @ T_world_actions


def moved_pose_rows(G: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Pose rows ``(F, 8)`` (xyz, quaternion xyzw, gripper) moved by the rigid transform ``G``."""
    out = rows.copy()
    for index, row in enumerate(rows):
        position, quat = pose_to_pos_quat(G @ pose_from_pos_quat(row[:3], row[3:7]))
        out[index, :3], out[index, 3:7] = position, quat
    return out


def moved_demo(G: np.ndarray, demo: Demonstration) -> Demonstration:
    points = np.stack([transform_points(G, cloud) for cloud in demo.points_world]).astype(np.float32)
    return Demonstration(points, moved_pose_rows(G, demo.state), moved_pose_rows(G, demo.action), demo.task)


@pytest.fixture(scope="module")
def policy():
    model = InstantPolicyPolicy(InstantPolicyConfig(device="cpu"))
    model.eval()
    return model


def test_predicted_chunk_is_absolute_poses_in_the_contract_layout(policy):
    policy.set_demonstrations(lift_demos(2))
    chunk = policy.predict_action_chunk(live_observation(batch=2), generator=torch.Generator().manual_seed(0))
    assert chunk.shape == (2, policy.config.horizon, 8) and torch.isfinite(chunk).all()
    assert torch.allclose(chunk[..., 3:7].norm(dim=-1), torch.ones(2, 8), atol=1e-5)
    assert (chunk[..., 6] >= 0).all()
    assert set(chunk[..., 7].unique().tolist()) <= {0.0, 1.0}
    # Action j is bounded by j · (1 cm per axis) relative to the current EE pose (the diffusion's normalisation).
    offsets = relative_actions(live_observation(batch=2), chunk)[..., :3, 3].abs().amax(dim=(0, 2))
    assert (offsets <= 0.01 * torch.arange(1, 9) + 1e-4).all()


def test_relative_actions_do_not_depend_on_where_the_world_is(policy):
    demos, observation = lift_demos(2), live_observation()
    G = make_pose(np.array([0.3, -0.7, 0.25]), Rotation.from_euler("xyz", [25.0, -40.0, 130.0], degrees=True))
    moved_observation = {
        POINTCLOUD_KEY: torch.from_numpy(transform_points(G, observation[POINTCLOUD_KEY][0].numpy()))[None].float(),
        STATE_KEY: torch.from_numpy(moved_pose_rows(G, observation[STATE_KEY].numpy())).float(),
        "task": [TASK],
    }
    policy.set_demonstrations(demos)
    original = policy.predict_action_chunk(observation, generator=torch.Generator().manual_seed(3))
    policy.set_demonstrations([moved_demo(G, demo) for demo in demos])
    moved = policy.predict_action_chunk(moved_observation, generator=torch.Generator().manual_seed(3))
    T_original, T_moved = relative_actions(observation, original), relative_actions(moved_observation, moved)
    assert torch.allclose(T_original, T_moved, atol=2e-4), (T_original - T_moved).abs().max()
    assert torch.equal(original[..., 7], moved[..., 7])
    # The absolute actions did move with the world (the test is not comparing two constants).
    assert not torch.allclose(original[..., :3], moved[..., :3], atol=1e-2)


def test_any_number_of_demonstrations_and_waypoints_at_inference(policy):
    observation = live_observation()
    for num_demos, num_waypoints in [(1, 4), (4, NUM_FRAMES), (2, 2)]:
        policy.set_demonstrations(lift_demos(num_demos), num_waypoints=num_waypoints)
        demos = policy.task_context(TASK).demos
        assert (demos.num_demos, demos.num_waypoints) == (num_demos, num_waypoints)
        chunk = policy.predict_action_chunk(observation, generator=torch.Generator().manual_seed(0))
        assert chunk.shape == (1, 8, 8) and torch.isfinite(chunk).all()


def test_select_action_runs_the_queue_and_replans_after_a_gripper_change(policy, monkeypatch):
    calls = []

    def fake_chunk(batch, **kwargs):
        calls.append(1)
        chunk = torch.zeros(1, 8, 8)
        chunk[..., 6] = 1.0
        chunk[..., 7] = torch.tensor([1, 1, 1, 0, 0, 0, 0, 0], dtype=torch.float32)  # closes at action 3
        return chunk

    monkeypatch.setattr(policy, "predict_action_chunk", fake_chunk)
    policy.reset()
    observation = live_observation()  # gripper open
    grippers = [float(policy.select_action(observation)[0, 7]) for _ in range(5)]
    # actions 0, 1, 2 (open), 3 (closes: queue dropped), then a new chunk's action 0
    assert grippers == [1.0, 1.0, 1.0, 0.0, 1.0] and len(calls) == 2
    policy.config.replan_on_gripper_change = False
    try:
        policy.reset()
        calls.clear()
        for _ in range(8):
            policy.select_action(observation)
        assert len(calls) == 1
    finally:
        policy.config.replan_on_gripper_change = True
    policy.reset()
    policy.select_action(observation)
    with pytest.raises(ValueError, match="batch size changed"):
        policy.select_action(live_observation(batch=2))
    policy.reset()


def test_denoising_starts_from_the_replayed_demonstration_at_the_episode_step(monkeypatch):
    """replay_init_strength: the guess is the best demonstration registered onto the live cloud, its actions from
    the episode's current step, in the current EE frame; reset() plans again for the next scene."""
    config = InstantPolicyConfig(device="cpu", replay_init_strength=0.5, max_translation=0.05, max_rotation_deg=30.0)
    policy = InstantPolicyPolicy(config).eval()
    policy.set_demonstrations(lift_demos(2))
    sampled = []

    def replay_exactly(context, initial=None, strength=1.0, **kwargs):  # the network's output: its guess, unchanged
        sampled.append(strength)
        T_ee_actions, gripper = policy.network.diffusion.unnormalize(initial)
        return T_ee_actions, (gripper > 0).float()

    monkeypatch.setattr(policy.network, "sample_actions", replay_exactly)
    for T_world_object, steps in ((object_pose(0.52, -0.05, 35.0), 3), (object_pose(0.42, 0.12, -50.0), 0)):
        policy.reset()
        demo = make_demonstration(T_world_object, TASK, seed=7)

        def observation(frame: int) -> dict:  # the EE where the replay has taken it; the scene planned at frame 0
            return {POINTCLOUD_KEY: torch.from_numpy(demo.points_world[frame:frame + 1]),
                    STATE_KEY: torch.from_numpy(demo.state[frame:frame + 1]), "task": [TASK]}

        for step in range(steps):
            policy.select_action(observation(step))
        chunk = policy.predict_action_chunk(observation(steps))[0].numpy()
        expected = expected_actions(T_world_object)[np.minimum(np.arange(steps, steps + 8), NUM_FRAMES - 1)]
        np.testing.assert_allclose(chunk[:, :3], expected[:, :3], atol=0.005)
        np.testing.assert_array_equal(chunk[:, 7], expected[:, 7])
    assert sampled and set(sampled) == {0.5}


def test_replay_trust_starts_from_noise_where_the_demonstrations_part_and_from_the_replay_where_they_agree(
        monkeypatch):
    """replay_trust_m: demonstrations that agree in the live scene keep replay_init_strength from the plan; a second
    demonstration whose actions miss its scene by 8 cm lifts the distrust past the range's end, and the episode
    starts from noise, as the paper's inference (initial None); rows of one batch keep their own starts."""
    config = InstantPolicyConfig(device="cpu", replay_init_strength=0.25, replay_trust_m=(0.02, 0.05))
    policy = InstantPolicyPolicy(config).eval()
    sampled = []

    def record_start(context, initial=None, strength=1.0, **kwargs):
        sampled.append((None if initial is None else len(initial), strength))
        return torch.eye(4).repeat(1, 8, 1, 1), torch.ones(1, 8)  # one row: the EE held

    monkeypatch.setattr(policy.network, "sample_actions", record_start)
    agreeing = lift_demos(2)
    missing = make_demonstration(object_pose(0.45, 0.1, 20.0), TASK, seed=1)
    missing.action[:, 0] += 0.08  # acted 8 cm beside the object its cloud shows
    for demonstrations, expected in ((agreeing, (1, 0.25)), ([agreeing[0], missing], (None, 1.0))):
        policy.set_demonstrations(demonstrations)
        policy.reset()
        sampled.clear()
        observation = live_observation(frame=0)
        policy.predict_action_chunk(observation)
        assert sampled == [expected]


def test_padded_actions_hold_the_last_real_action():
    actions = torch.arange(2 * 4 * 8, dtype=torch.float32).view(2, 4, 8)
    is_pad = torch.tensor([[False, False, True, True], [False, False, False, False]])
    held = hold_padded(actions, is_pad)
    assert torch.equal(held[0, 2], actions[0, 1]) and torch.equal(held[0, 3], actions[0, 1])
    assert torch.equal(held[0, :2], actions[0, :2]) and torch.equal(held[1], actions[1])


# ---------------------------------------------------------------------------------------------- training


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    """Three lift demonstrations (12 frames each) as a LeRobotDataset with ``horizon`` action chunks."""
    from lerobot.datasets import LeRobotDataset

    root = tmp_path_factory.mktemp("ip_policy") / "tiny"
    poses = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0), object_pose(0.4, 0.15, 55.0)]
    write_demo_dataset(root, REPO, [(TASK, pose) for pose in poses])
    delta = {ACTION_KEY: [step / 10 for step in range(8)]}
    return LeRobotDataset(REPO, root=root, delta_timestamps=delta)


def test_loss_falls_when_overfitting_a_tiny_dataset(tiny_dataset):
    torch.manual_seed(0)
    config = InstantPolicyConfig(device="cpu", optimizer_lr=1e-3, reencode_action_clouds=False, max_demos=1)
    policy = InstantPolicyPolicy(config, dataset_meta=tiny_dataset.meta)
    frames = [0, 4, 8, 12, 17, 26]  # descending, grasping and lifting frames of the three episodes
    batch = next(iter(torch.utils.data.DataLoader(torch.utils.data.Subset(tiny_dataset, frames), batch_size=6)))
    optimizer = torch.optim.AdamW(policy.get_optim_params(), lr=config.optimizer_lr)
    policy.train()
    losses = []
    for _ in range(30):
        loss, parts = policy.forward(batch)
        assert set(parts) == {"translation", "rotation", "gripper", "num_demos"}
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    first, last = np.mean(losses[:5]), np.mean(losses[-5:])
    assert last < 0.6 * first, losses
    # The frozen encoder never changes, and the training bank stays out of the state dict.
    assert not any(key.startswith("_training_bank") for key in policy.state_dict())
    assert all(not parameter.requires_grad for parameter in policy.network.geometry_encoder.parameters())
    # Every frame and waypoint came from the frame-encoding cache beside the dataset: nothing else was encoded.
    encoder = policy.training_data.context_encoder()
    assert encoder.frame_encodings is not None and encoder.bank.points_world is None


@pytest.mark.parametrize("dense", [True, False])
def test_a_policy_that_predicted_can_still_train(tiny_dataset, dense):
    """Inference runs in torch's inference mode; the graph connectivity it builds and caches (per size) must still
    serve a training step of the same process, in the network's dense layout and in the torch-geometric reference."""
    from lerobot_instant_policy.model import dense_graphs, sparse_graphs

    for cached in (sparse_graphs.local_graph, sparse_graphs.context_graph, sparse_graphs.action_graph,
                   dense_graphs.dense_local_masks, dense_graphs.dense_action_masks):
        cached.cache_clear()  # built first by the prediction below
    torch.manual_seed(0)
    config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, max_demos=2)
    policy = InstantPolicyPolicy(config, dataset_meta=tiny_dataset.meta).eval()
    if not dense:
        network = policy.network
        network.graphs = sparse_graphs.SparseGraphs(network.local_network, network.context_network,
                                                    network.action_network, config.num_frequencies)
    policy.set_demonstrations(lift_demos(2))
    policy.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(0))
    policy.train()
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=1, shuffle=False)))
    loss, _ = policy.forward(batch)
    loss.backward()
    assert all(torch.isfinite(p.grad).all() for p in policy.get_optim_params() if p.grad is not None)


# CI: the shipped graph; the paper's (about 30 s of compiling more) with the slow tests
@pytest.mark.parametrize("action_scene_graph", [pytest.param(True, marks=pytest.mark.slow), False])
def test_compiled_training_step_gives_the_eager_loss_and_gradients(tiny_dataset, action_scene_graph):
    """``--policy.compile_model``: σ, φ and ψ through ``torch.compile`` in the training step give the eager step's
    loss and gradients (the same weights and random draws), in the paper's graph and the shipped one; sampling runs
    the eager layers."""
    sizes = dict(device="cpu", hidden_dim=32, num_heads=2, local_layers=1, context_layers=1, action_layers=1,
                 action_scene_graph=action_scene_graph)
    eager = InstantPolicyPolicy(InstantPolicyConfig(**sizes), dataset_meta=tiny_dataset.meta).train()
    compiled = InstantPolicyPolicy(InstantPolicyConfig(**sizes, compile_model=True), dataset_meta=tiny_dataset.meta)
    compiled.load_state_dict(eager.state_dict())
    compiled.train()
    networks = (compiled.network.local_network, compiled.network.context_network, compiled.network.action_network)
    calls = []
    for network in networks:
        run = network._compiled_dense
        network._compiled_dense = lambda *args, run=run, network=network: calls.append(network) or run(*args)
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=4, shuffle=False)))
    results = []
    for policy in (eager, compiled):
        torch.manual_seed(3)
        loss, parts = policy.forward(batch)
        loss.backward()
        results.append((loss.detach(), parts, [p.grad for p in policy.get_optim_params()]))
    # σ on the demonstrations and the current frame, φ, then σ on the action nodes (the paper's graph only) and ψ
    assert calls == [networks[0], networks[1], *([networks[0]] if action_scene_graph else []), networks[2]]
    (eager_loss, eager_parts, eager_grads), (compiled_loss, compiled_parts, compiled_grads) = results
    torch.testing.assert_close(compiled_loss, eager_loss, atol=1e-5, rtol=1e-5)
    assert compiled_parts["num_demos"] == eager_parts["num_demos"]
    for compiled_grad, eager_grad in zip(compiled_grads, eager_grads, strict=True):
        torch.testing.assert_close(compiled_grad, eager_grad, atol=1e-5, rtol=1e-4)
    compiled.eval()
    compiled.set_demonstrations(lift_demos(2))
    compiled.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(0))
    assert len(calls) == (4 if action_scene_graph else 3)  # sampling did not call the compiled layers


# CI: the shipped graph; the paper's with the slow tests
@pytest.mark.parametrize("action_scene_graph", [pytest.param(True, marks=pytest.mark.slow), False])
def test_compiled_sampling_gives_the_eager_actions(action_scene_graph):
    """``--policy.compile_inference``: σ, φ and ψ through ``torch.compile`` under ``inference_mode`` predict the eager
    policy's action chunk (the same weights and DDIM noise), in the paper's graph and the shipped one; the compiled
    layers are the ones run."""
    sizes = dict(device="cpu", reencode_action_clouds=False, max_demos=2, hidden_dim=32, num_heads=2,
                 local_layers=1, context_layers=1, action_layers=1, inference_steps=2,
                 action_scene_graph=action_scene_graph)
    eager = InstantPolicyPolicy(InstantPolicyConfig(**sizes)).eval()
    compiled = InstantPolicyPolicy(InstantPolicyConfig(**sizes, compile_inference=True)).eval()
    compiled.load_state_dict(eager.state_dict())
    networks = (compiled.network.local_network, compiled.network.context_network, compiled.network.action_network)
    calls = []
    for network in networks:
        run = network._compiled_dense
        network._compiled_dense = lambda *args, run=run, network=network: calls.append(network) or run(*args)
    chunks = []
    for policy in (eager, compiled):
        policy.set_demonstrations(lift_demos(2))
        chunks.append(policy.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(0)))
    torch.testing.assert_close(chunks[1], chunks[0], atol=1e-5, rtol=1e-5)
    assert set(calls) == set(networks)  # σ, φ and ψ all ran compiled


def test_gripper_flip_probability_changes_the_current_gripper_state(tiny_dataset, monkeypatch):
    policy = InstantPolicyPolicy(InstantPolicyConfig(device="cpu", gripper_flip_probability=1.0),
                                 dataset_meta=tiny_dataset.meta)
    seen = []
    encode_context = policy.network.encode_context
    monkeypatch.setattr(policy.network, "encode_context",
                        lambda *args, **kwargs: seen.append(args[3].clone()) or encode_context(*args, **kwargs))
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=4, shuffle=False)))
    policy.forward(batch)
    assert torch.equal(seen[0], 1.0 - (batch[STATE_KEY][:, 7] > 0.5).float())
    policy.config.gripper_flip_probability = 0.0
    policy.forward(batch)
    assert torch.equal(seen[1], (batch[STATE_KEY][:, 7] > 0.5).float())


def test_training_needs_the_dataset_and_an_episode_index(tiny_dataset):
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=2, shuffle=False)))
    with pytest.raises(RuntimeError, match="dataset_meta"):
        InstantPolicyPolicy(InstantPolicyConfig(device="cpu")).forward(batch)
    policy = InstantPolicyPolicy(InstantPolicyConfig(device="cpu"), dataset_meta=tiny_dataset.meta)
    with pytest.raises(KeyError, match="episode_index"):
        policy.forward({key: value for key, value in batch.items() if key != "episode_index"})
    with pytest.raises(ValueError, match="action"):
        policy.forward({**batch, ACTION_KEY: batch[ACTION_KEY][:, :3]})
    with pytest.raises(DemonstrationError, match="needs at least 20 frames"):  # read when the policy is built
        InstantPolicyPolicy(InstantPolicyConfig(device="cpu", num_waypoints=20), dataset_meta=tiny_dataset.meta)


# ---------------------------------------------------------------------------------------------- bad input


def test_bad_observations_are_refused_with_clear_errors(policy):
    policy.set_demonstrations(lift_demos(2))
    observation = live_observation()
    nan_cloud = observation[POINTCLOUD_KEY].clone()
    nan_cloud[0, 5, 1] = float("nan")
    with pytest.raises(ValueError, match="observation.pointcloud.*NaN"):
        policy.predict_action_chunk({**observation, POINTCLOUD_KEY: nan_cloud})
    nan_state = observation[STATE_KEY].clone()
    nan_state[0, 0] = float("nan")
    with pytest.raises(ValueError, match="observation.state.*NaN"):
        policy.select_action({**observation, STATE_KEY: nan_state})
    with pytest.raises(ValueError, match="wrong size.*2048"):
        policy.predict_action_chunk({**observation, POINTCLOUD_KEY: observation[POINTCLOUD_KEY][:, :1000]})
    with pytest.raises(KeyError, match="observation.pointcloud"):
        policy.predict_action_chunk({STATE_KEY: observation[STATE_KEY], "task": [TASK]})
    with pytest.raises(DemonstrationError, match="no demonstrations of task 'stack'"):
        policy.predict_action_chunk({**observation, "task": ["stack"]})


def test_bad_demonstrations_are_refused_with_clear_errors(policy):
    demos = lift_demos(4)
    with pytest.raises(ValueError, match=r"the number of demonstrations N must be an integer in the supported range "
                       r"1…8, got 9"):
        policy.set_demonstrations(demos * 2 + demos[:1])
    with pytest.raises(ValueError, match=r"num_waypoints \(L\) must be an integer in the supported range 2…32, got 1"):
        policy.set_demonstrations(demos[:2], num_waypoints=1)
    with pytest.raises(ValueError, match=r"num_waypoints \(L\) .* got 33"):
        policy.set_demonstrations(demos[:2], num_waypoints=33)
    with pytest.raises(DemonstrationError, match="cannot give 20 waypoints"):
        policy.set_demonstrations(demos[:2], num_waypoints=20)
    small = Demonstration(demos[0].points_world[:, :512], demos[0].state, demos[0].action, TASK)
    with pytest.raises(ValueError, match="wrong size.*512 points"):
        policy.set_demonstrations([small])
    with pytest.raises(DemonstrationError, match="one task"):
        policy.set_demonstrations([demos[0], make_demonstration(object_pose(0.5, 0, 0), "push", seed=0)])


def _write_dataset_without(root: Path, missing: str) -> None:
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.data.lerobot_format import contract_features

    features = {key: value for key, value in contract_features().items() if key != missing}
    dataset = LeRobotDataset.create("local/broken", fps=10, features=features, root=root, use_videos=False)
    demo = lift_demos(1)[0]
    rows = {POINTCLOUD_KEY: demo.points_world, STATE_KEY: demo.state, ACTION_KEY: demo.action}
    for frame in range(3):
        dataset.add_frame({**{key: rows[key][frame] for key in features}, "task": TASK})
    dataset.save_episode()
    dataset.finalize()


@pytest.mark.parametrize("missing", [POINTCLOUD_KEY, STATE_KEY])
def test_demo_dataset_without_point_clouds_or_ee_poses_is_refused(tmp_path, missing):
    _write_dataset_without(tmp_path / "broken", missing)
    config = InstantPolicyConfig(device="cpu", demo_repo_id="local/broken", demo_root=str(tmp_path / "broken"))
    with pytest.raises(DemonstrationError, match=f"missing key '{missing}'"):
        InstantPolicyPolicy(config)


def test_demo_dataset_without_the_task_or_with_too_few_frames(tiny_dataset):
    root = str(tiny_dataset.root)
    policy = InstantPolicyPolicy(InstantPolicyConfig(device="cpu", demo_repo_id=REPO, demo_root=root))
    with pytest.raises(DemonstrationError, match="no episode of task 'stack'.*lift"):
        policy.predict_action_chunk({**live_observation(), "task": ["stack"]})
    chunk = policy.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(0))
    assert chunk.shape == (1, 8, 8) and policy.task_context(TASK).demos.num_demos == 2
    long = InstantPolicyPolicy(InstantPolicyConfig(device="cpu", demo_repo_id=REPO, demo_root=root, num_waypoints=13))
    with pytest.raises(DemonstrationError, match="12 frames cannot give 13 waypoints"):
        long.predict_action_chunk(live_observation())


# ---------------------------------------------------------------------------------------------- checkpoints


def _predict(policy: InstantPolicyPolicy) -> torch.Tensor:
    policy.set_demonstrations(lift_demos(2))
    return policy.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(5))


def test_sigma_on_the_demonstrations_runs_once_per_task_and_again_after_the_weights_change(monkeypatch):
    torch.manual_seed(0)
    model = InstantPolicyPolicy(InstantPolicyConfig(device="cpu", reencode_action_clouds=False)).eval()
    calls = []
    encode = model.network.encode_demo_waypoints
    monkeypatch.setattr(model.network, "encode_demo_waypoints", lambda *args: calls.append(1) or encode(*args))
    first = _predict(model)
    again = model.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(5))
    assert len(calls) == 1 and torch.equal(first, again)
    # The cached σ features give what the joint computation (σ on demos and live frame together) gives.
    task_context = model.task_context(TASK)
    observation = live_observation()
    T_world_ee, gripper = poses_from_vectors_torch(observation[STATE_KEY])
    with torch.no_grad():
        joint = model.network.encode_context(task_context.demos, observation[POINTCLOUD_KEY], T_world_ee, gripper)
        cached = model.network.encode_context(task_context.demos, observation[POINTCLOUD_KEY], T_world_ee, gripper,
                                              demo_waypoint_features=task_context.waypoint_features)
    torch.testing.assert_close(cached.current_gripper_features, joint.current_gripper_features)
    # An optimizer step changes σ's weights: the cached features are recomputed, not reused.
    optimizer = torch.optim.SGD(model.get_optim_params(), lr=0.1)
    for parameter in model.get_optim_params():
        parameter.grad = torch.ones_like(parameter)
    optimizer.step()
    model.predict_action_chunk(live_observation(), generator=torch.Generator().manual_seed(5))
    assert len(calls) == 2  # the comparison reused the cache; the step forced a second computation


def test_save_and_load_round_trip_with_processors(policy, tmp_path):
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action

    preprocessor, postprocessor = make_instant_policy_pre_post_processors(policy.config)
    policy.save_pretrained(tmp_path)
    preprocessor.save_pretrained(tmp_path)
    postprocessor.save_pretrained(tmp_path)
    loaded = InstantPolicyPolicy.from_pretrained(tmp_path)
    assert loaded.config.hidden_dim == policy.config.hidden_dim and not loaded.training
    for key, value in policy.state_dict().items():
        assert torch.equal(value, loaded.state_dict()[key]), key
    assert torch.equal(_predict(policy), _predict(loaded))

    pre = PolicyProcessorPipeline.from_pretrained(tmp_path, config_filename="policy_preprocessor.json")
    post = PolicyProcessorPipeline.from_pretrained(
        tmp_path, config_filename="policy_postprocessor.json", to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    observation = live_observation()
    processed = pre(dict(observation))
    for key in (POINTCLOUD_KEY, STATE_KEY):
        assert torch.equal(processed[key], observation[key])  # identity normalisation
    action = loaded.select_action(processed)
    assert torch.equal(post(action), action)
    loaded.reset()


def test_a_checkpoint_that_does_not_match_its_config_is_refused(policy, tmp_path):
    policy.save_pretrained(tmp_path)
    config_file = tmp_path / "config.json"
    saved = json.loads(config_file.read_text())
    config_file.write_text(json.dumps({**saved, "context_layers": 3}))
    with pytest.raises(CheckpointMismatchError, match="34 missing tensors.*context_network.layers.1"):
        InstantPolicyPolicy.from_pretrained(tmp_path)
    config_file.write_text(json.dumps({**saved, "hidden_dim": 64}))
    with pytest.raises(CheckpointMismatchError, match="size mismatch"):
        InstantPolicyPolicy.from_pretrained(tmp_path)


def test_push_to_hub_uploads_a_loadable_policy(policy, tmp_path, monkeypatch):
    import huggingface_hub
    import lerobot.utils.hub

    uploads = []

    class RecordingHfApi:
        def __init__(self, *args, **kwargs):
            pass

        def create_repo(self, repo_id, **kwargs):
            return huggingface_hub.RepoUrl(f"https://huggingface.co/{repo_id}")

        def upload_folder(self, repo_id, folder_path, **kwargs):
            copy = tmp_path / "uploaded" / str(len(uploads))
            copy.mkdir(parents=True)
            for path in Path(folder_path).iterdir():
                (copy / path.name).write_bytes(path.read_bytes())
            uploads.append({"repo_id": repo_id, "files": sorted(p.name for p in copy.iterdir()), "copy": copy, **kwargs})
            return f"https://huggingface.co/{repo_id}/commit/0"

    monkeypatch.setattr(huggingface_hub, "HfApi", RecordingHfApi)
    monkeypatch.setattr(lerobot.utils.hub, "HfApi", RecordingHfApi)
    policy.push_to_hub("someone/instant-policy-test")
    assert len(uploads) == 1 and uploads[0]["repo_id"] == "someone/instant-policy-test"
    assert {"config.json", "model.safetensors"} <= set(uploads[0]["files"])
    loaded = InstantPolicyPolicy.from_pretrained(uploads[0]["copy"])
    assert torch.equal(_predict(policy), _predict(loaded))


def test_n_is_capped_so_that_no_demonstration_repeats(tiny_dataset, monkeypatch):
    """The tiny task has 3 episodes, so a frame has 2 others: N drawn up to 5 becomes at most 2, never a repeat."""
    policy = InstantPolicyPolicy(InstantPolicyConfig(device="cpu", min_demos=4, max_demos=5),
                                 dataset_meta=tiny_dataset.meta)
    drawn = []
    bank = policy.training_data.context_encoder().bank
    sample_context = bank.sample_context
    monkeypatch.setattr(bank, "sample_context",
                        lambda episode, n, rng: drawn.append(sample_context(episode, n, rng)) or drawn[-1])
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=4, shuffle=False)))
    _, parts = policy.forward(batch)
    assert parts["num_demos"] == 2.0
    assert all(len(set(context.tolist())) == len(context) == 2 for context in drawn)
    assert all(int(episode) not in context for episode, context in zip(batch["episode_index"], drawn, strict=True))


# ---------------------------------------------------------------------------------------------- a batch's own context


def _carried_context(bank, episodes: np.ndarray, ids: list[int]) -> dict:
    """The context keys of a batch that carries the waypoints of ``episodes (B, N)`` of ``bank``."""
    arrays = bank.gather(episodes)
    return {
        CONTEXT_POINTCLOUD_KEY: torch.from_numpy(arrays.points_world),
        CONTEXT_T_WORLD_EE_KEY: torch.from_numpy(arrays.T_world_ee),
        CONTEXT_GRIPPER_OPEN_KEY: torch.from_numpy(arrays.gripper_open),
        CONTEXT_ID_KEY: torch.tensor(ids, dtype=torch.int64),
    }


def test_a_batch_that_carries_its_context_trains_as_the_datasets_context_does(tiny_dataset, monkeypatch):
    """The pseudo-task stream hands each row its context (``contract.CONTEXT_KEYS``). Handed the demonstrations the
    dataset's bank draws, the loss is the dataset path's; the frozen encoder runs once per distinct context id."""
    from lerobot_instant_policy.data.context_bank import ContextBank

    config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, min_demos=2, max_demos=2)
    policy = InstantPolicyPolicy(config, dataset_meta=tiny_dataset.meta).train()
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=4, shuffle=False)))  # episode 0's frames
    bank = policy.training_data.context_encoder().bank
    monkeypatch.setattr(bank, "sample_context", lambda episode, n, rng: np.array([1, 2]))
    torch.manual_seed(3)
    dataset_loss, _ = policy.forward(batch)

    with_points = ContextBank.from_dataset(REPO, tiny_dataset.root, config.num_waypoints)
    carried = {key: value for key, value in batch.items() if key not in ("episode_index", "index")}
    carried.update(_carried_context(with_points, np.array([[1, 2]] * 4), ids=[7, 7, 9, 9]))
    encoded = []
    encode_observation = policy.network.encode_observation
    monkeypatch.setattr(policy.network, "encode_observation",
                        lambda points, T: encoded.append(points.shape[:3]) or encode_observation(points, T))
    torch.manual_seed(3)
    carried_loss, parts = policy.forward(carried)

    torch.testing.assert_close(carried_loss, dataset_loss, rtol=1e-4, atol=1e-5)
    assert parts["num_demos"] == 2.0
    assert encoded[0] == (2, 2, config.num_waypoints)  # the two distinct contexts, then the live clouds
    carried_loss.backward()
    assert all(parameter.grad is not None for parameter in policy.get_optim_params()[:3])


def test_a_carried_context_that_is_malformed_is_refused_by_name(tiny_dataset):
    from lerobot_instant_policy.data.context_bank import ContextBank

    config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False)
    policy = InstantPolicyPolicy(config).train()  # no dataset: the batch brings everything
    batch = next(iter(torch.utils.data.DataLoader(tiny_dataset, batch_size=2, shuffle=False)))
    batch = {key: value for key, value in batch.items() if key not in ("episode_index", "index")}
    bank = ContextBank.from_dataset(REPO, tiny_dataset.root, config.num_waypoints)
    context = _carried_context(bank, np.array([[1, 2], [1, 2]]), ids=[0, 0])
    loss, _ = policy.forward({**batch, **context})
    assert torch.isfinite(loss)
    with pytest.raises(KeyError, match="observation.context.id"):
        policy.forward({**batch, **{key: value for key, value in context.items() if key != CONTEXT_ID_KEY}})
    with pytest.raises(ValueError, match="observation.context.pointcloud"):
        policy.forward({**batch, **context, CONTEXT_POINTCLOUD_KEY: context[CONTEXT_POINTCLOUD_KEY][..., :100, :]})
    bad = context[CONTEXT_GRIPPER_OPEN_KEY].clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        policy.forward({**batch, **context, CONTEXT_GRIPPER_OPEN_KEY: bad})
    with pytest.raises(ValueError, match=r"\(B, N, L, 4, 4\)"):
        policy.forward({**batch, **context, CONTEXT_T_WORLD_EE_KEY: context[CONTEXT_T_WORLD_EE_KEY][0]})
