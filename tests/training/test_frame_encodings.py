"""The frozen encoder's per-frame cache (issue 12): it holds exactly what live encoding gives, training with it
computes the same loss as without it, and it is rebuilt, never trusted, when the encoder or the dataset changes
or a build was interrupted."""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
import torch
from synthetic_demos import object_pose, write_demo_dataset

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import POINTCLOUD_KEY, STATE_KEY, poses_from_vectors_torch
from lerobot_instant_policy.data.context_bank import ContextBank
from lerobot_instant_policy.model.fingerprint import encoder_fingerprint
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.training.batches import encode_frames
from lerobot_instant_policy.training.context_encoder import ContextEncoder
from lerobot_instant_policy.training.frame_encodings import (
    CACHE_DIR,
    META_FILE,
    build_frame_encodings,
    cache_path,
    load_frame_encodings,
)

REPO = "local/ip_frame_cache"


@pytest.fixture()
def dataset(tmp_path):
    """Two tasks × 3 episodes (12 frames each) with 8-step action chunks, in a fresh directory per test."""
    from lerobot.datasets import LeRobotDataset

    poses = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0), object_pose(0.4, 0.15, 55.0)]
    write_demo_dataset(tmp_path / "data", REPO, [(task, pose) for task in ("lift", "push") for pose in poses])
    return LeRobotDataset(REPO, root=tmp_path / "data", delta_timestamps={"action": [step / 10 for step in range(8)]})


def _policy(dataset, **overrides) -> InstantPolicyPolicy:
    torch.manual_seed(0)
    config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, max_demos=2, **overrides)
    return InstantPolicyPolicy(config, dataset_meta=dataset.meta).train()


def _fingerprint(policy: InstantPolicyPolicy) -> str:
    return encoder_fingerprint(policy.network.geometry_encoder, policy.config.encoder_config.to_dict())


def test_cached_scene_nodes_are_the_live_encoding_of_each_frame(dataset):
    policy = _policy(dataset)
    encodings = policy.training_data.context_encoder().frame_encodings
    assert len(encodings) == dataset.num_frames
    assert encodings.path == cache_path(dataset.root, _fingerprint(policy))
    frames = [0, 7, 13, 30, len(dataset) - 1]
    rows = dataset.hf_dataset.with_format("torch", columns=[POINTCLOUD_KEY, STATE_KEY])[frames]
    T_world_ee, _ = poses_from_vectors_torch(rows[STATE_KEY])
    live = policy.network.encode_observation(rows[POINTCLOUD_KEY], T_world_ee)
    cached = encodings.lookup(np.array(frames))
    for live_part, cached_part in zip(live, cached, strict=True):
        assert cached_part.dtype == torch.float32
        torch.testing.assert_close(cached_part, live_part, rtol=1e-5, atol=1e-6)
    # Indices keep their shape: (2, 2) frames → (2, 2, M, 3) positions.
    assert encodings.lookup(np.array([[0, 1], [2, 3]]))[0].shape == (2, 2, *live[0].shape[1:])
    with pytest.raises(IndexError, match="outside"):
        encodings.lookup(np.array([dataset.num_frames]))


def test_training_with_the_cache_computes_the_loss_of_live_encoding(dataset):
    batch = next(iter(torch.utils.data.DataLoader(dataset, batch_size=6, shuffle=True,
                                                  generator=torch.Generator().manual_seed(1))))
    losses = {}
    for cached in (True, False):
        policy = _policy(dataset, cache_frame_encodings=cached)
        torch.manual_seed(3)
        loss, parts = policy.forward(batch)
        loss.backward()
        losses[cached] = (float(loss.detach()), parts)
        # Without the cache the context encoder encodes the context episodes' clouds itself; with it, the bank was
        # read without them, so everything came from the cache.
        encoder = policy.training_data.context_encoder()
        assert (encoder.bank.points_world is None) == cached
        assert (encoder.frame_encodings is not None) == cached
    assert losses[True][0] == pytest.approx(losses[False][0], rel=1e-4)
    assert losses[True][1]["num_demos"] == losses[False][1]["num_demos"]


def test_a_cache_is_reused_and_rebuilt_when_the_dataset_or_the_encoder_changes(dataset):
    policy = _policy(dataset)
    fingerprint = _fingerprint(policy)
    path = policy.training_data.context_encoder().frame_encodings.path
    built_at = (path / META_FILE).stat().st_mtime_ns
    # A second policy with the same encoder reuses the cache (no rebuild).
    assert _policy(dataset).training_data.context_encoder().frame_encodings.path == path
    assert (path / META_FILE).stat().st_mtime_ns == built_at

    # A dataset whose files changed makes the cache stale: not loaded, rebuilt in place by the next policy.
    meta = json.loads((path / META_FILE).read_text())
    meta["dataset"]["data_files"][0][1] += 1
    (path / META_FILE).write_text(json.dumps(meta))
    assert load_frame_encodings(dataset.root, fingerprint) is None
    rebuilt = _policy(dataset).training_data.context_encoder().frame_encodings
    assert rebuilt.path == path and load_frame_encodings(dataset.root, fingerprint) is not None

    # Other encoder weights get a cache of their own.
    other = _policy(dataset)
    with torch.no_grad():
        next(other.network.geometry_encoder.parameters()).add_(0.01)
    other.clear_context_caches()
    assert other.training_data.context_encoder().frame_encodings.path != path
    assert len(list((dataset.root / CACHE_DIR).iterdir())) == 2


def test_an_interrupted_build_leaves_no_cache_and_no_debris(dataset):
    policy = _policy(dataset)
    fingerprint = _fingerprint(policy)
    calls = []
    # a build killed earlier by a signal left its temporary directory behind (its process is gone)
    path = cache_path(dataset.root, fingerprint)
    (path.parent / f".{path.name}.tmp-999999999").mkdir(parents=True)

    def failing_encode(points_world, state):
        calls.append(len(points_world))
        if len(calls) == 2:
            raise KeyboardInterrupt
        return encode_frames(policy.network, points_world, state)

    with pytest.raises(KeyboardInterrupt):
        build_frame_encodings(dataset, fingerprint, failing_encode, "cpu", batch_size=16)
    assert load_frame_encodings(dataset.root, fingerprint) is None
    assert list((dataset.root / CACHE_DIR).iterdir()) == []
    # The next build starts over and succeeds.
    assert len(build_frame_encodings(dataset, fingerprint, functools.partial(encode_frames, policy.network), "cpu",
                                     batch_size=16)) == 72


def test_frame_encodings_need_a_bank_read_from_their_dataset(dataset):
    from lerobot_instant_policy.data.demonstrations import load_demonstrations

    policy = _policy(dataset)
    encodings = policy.training_data.context_encoder().frame_encodings
    demonstrations = load_demonstrations(REPO, dataset.root, "lift", 3)
    handed_in = ContextBank.from_demonstrations(demonstrations, policy.config.num_waypoints)
    with pytest.raises(ValueError, match="from their dataset"):
        policy.set_training_bank(handed_in, frame_encodings=encodings)
    bank = ContextBank.from_dataset(REPO, dataset.root, policy.config.num_waypoints)
    assert bank.has_dataset_indices and not handed_in.has_dataset_indices
    # The waypoints' global indices point at the frames the bank holds.
    episode = int(bank.episode_indices[4])
    indices = bank.dataset_indices(np.array([episode]))[0]
    points = dataset.hf_dataset.with_format("numpy", columns=[POINTCLOUD_KEY])[indices.tolist()][POINTCLOUD_KEY]
    np.testing.assert_array_equal(points, bank.points_world[bank.episode_indices.tolist().index(episode)])


def test_a_bank_read_without_clouds_keeps_poses_and_indices_and_needs_frame_encodings(dataset):
    full = ContextBank.from_dataset(REPO, dataset.root, 10)
    light = ContextBank.from_dataset(REPO, dataset.root, 10, read_points=False)
    assert light.num_points is None and full.num_points == dataset.meta.features[POINTCLOUD_KEY]["shape"][0]
    episodes = np.array([[0, 4], [5, 1]])
    np.testing.assert_array_equal(light.dataset_indices(episodes), full.dataset_indices(episodes))
    np.testing.assert_array_equal(light.gather(episodes).T_world_ee, full.gather(episodes).T_world_ee)
    assert light.gather(episodes).points_world is None
    with pytest.raises(ValueError, match="read without its clouds: give the frame encodings"):
        ContextEncoder(_policy(dataset).network, light)


def test_training_refuses_a_dataset_with_clouds_of_another_size(dataset):
    from lerobot.configs.types import FeatureType, PolicyFeature

    torch.manual_seed(0)
    config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, max_demos=2)
    config.input_features[POINTCLOUD_KEY] = PolicyFeature(type=FeatureType.STATE, shape=(1024, 3))
    with pytest.raises(ValueError, match="point clouds of the wrong size"):
        InstantPolicyPolicy(config, dataset_meta=dataset.meta)
    assert not (dataset.root / CACHE_DIR).exists()  # refused before anything was encoded or written
