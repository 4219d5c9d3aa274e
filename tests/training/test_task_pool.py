"""The rolling pool of encoded fresh tasks (``training.task_pool``): the frozen encoder's reading of the stream's
clouds, the stream's loss from encoded frames, the stream's disjoint task indices across processes and generators,
uses counted, the oldest task replaced, and clear refusals."""

from __future__ import annotations

import itertools
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import (
    ACTION_KEY,
    CONTEXT_ID_KEY,
    CONTEXT_SCENE_FEATURES_KEY,
    CONTEXT_SCENE_POSITIONS_KEY,
    ENCODED_KEYS,
    SCENE_FEATURES_KEY,
    STATE_KEY,
    poses_from_vectors,
)
from lerobot_instant_policy.model.geometry_encoder import encoder_preset
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig
from lerobot_instant_policy.pseudo_demos.stream import PseudoTaskStream, StreamConfig
from lerobot_instant_policy.training.stream_seam import make_stream_datasets
from lerobot_instant_policy.training.task_pool import (
    EncoderSource,
    PoolConfig,
    TaskPool,
    encode_task,
    frozen_encoder,
)

SHIPPED = "lerobot_instant_policy/assets/checkpoints/instant_policy"
WEIGHTS = InstantPolicyConfig(device="cpu").encoder_weights_path()


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread(single_torch_thread):
    yield


def stream_config(**overrides) -> StreamConfig:
    """The policy's N, L, T and P with cheap splatting, one task per render, two live frames per task."""
    values = dict(generation=GenerationConfig(seed=11), num_demos=2, num_waypoints=10, horizon=8, samples_per_task=2,
                  tasks_per_render=1, surface_samples=1024, zbuffer_resolution=(160, 120))
    return StreamConfig(**(values | overrides))


@pytest.fixture(scope="module")
def rendered():
    return PseudoTaskStream(stream_config()).render_tasks([3])[0]


def test_an_encoded_task_is_the_policys_reading_of_its_clouds(rendered):
    policy = InstantPolicyPolicy.from_pretrained(SHIPPED)
    encoded = encode_task(rendered, EncoderSource(policy.config.encoder_config, checkpoint=SHIPPED).build(), 8)
    T_live = torch.as_tensor(poses_from_vectors(encoded.state)[0], dtype=torch.float32)
    positions, features = policy.network.encode_observation(rendered.live_clouds, T_live)
    assert np.array_equal(positions.numpy(), encoded.live_positions)
    assert np.array_equal(features.numpy(), encoded.live_features)
    T_context = torch.as_tensor(rendered.frames.T_world_ee, dtype=torch.float32)
    positions, features = policy.network.encode_observation(rendered.context_clouds, T_context)
    assert np.array_equal(positions.numpy(), encoded.scene_positions)
    assert np.array_equal(features.numpy(), encoded.scene_features)
    assert encoded.scene_features.shape == (2, 10, 16, 256) and encoded.actions.shape == (2, 8, 8)
    # The checkpoint carries the pretrained encoder it was trained with: both sources read alike.
    from_weights = encode_task(rendered, EncoderSource(policy.config.encoder_config, weights=str(WEIGHTS)).build(), 8)
    assert np.array_equal(from_weights.live_features, encoded.live_features)


def test_encoded_frames_train_with_the_streams_loss(rendered):
    """Same task, same live frames: the pool's encoded batch and the stream's batch of clouds give one loss."""
    config = InstantPolicyConfig(device="cpu", reencode_action_clouds=False, min_demos=2, max_demos=2)
    policy = InstantPolicyPolicy(config).train()
    stream = PseudoTaskStream(stream_config())
    clouds = torch.utils.data.default_collate(stream._task_samples(rendered))
    encoded = encode_task(rendered, EncoderSource(config.encoder_config, weights=str(WEIGHTS)).build(), 8)
    pooled = torch.utils.data.default_collate([encoded.sample(0), encoded.sample(1)])
    assert set(pooled) == {*ENCODED_KEYS, STATE_KEY, ACTION_KEY}
    torch.manual_seed(5)
    stream_loss, _ = policy.forward(clouds)
    torch.manual_seed(5)
    pool_loss, parts = policy.forward(pooled)
    torch.testing.assert_close(pool_loss, stream_loss, rtol=1e-5, atol=1e-6)
    assert parts["num_demos"] == 2.0
    pool_loss.backward()
    assert all(parameter.grad is not None for parameter in policy.get_optim_params()[:3])


def test_the_pool_draws_disjoint_tasks_counts_uses_and_replaces_the_oldest():
    """Rank 1 of 2 with 2 generators from task 10: indices 10 + 4k + 2 + g (the stream's scheme), each task the
    same as one encoded here from its index, at most ``capacity`` held, every draw counted."""
    config = PoolConfig(stream=stream_config(), capacity=3, min_tasks=3, generators=2, queue_size=2, seed=4)
    source = EncoderSource(encoder_preset("small"), weights=str(WEIGHTS))
    pool = TaskPool(config, source, rank=1, world_size=2, start_task=10)
    try:
        samples = list(itertools.islice(pool, 12))
        pool.receive(block=True)
        stats = pool.stats()
    finally:
        pool.close()
    assert not any(process.is_alive() for process in pool._context.active_children())
    ids = sorted({int(sample[CONTEXT_ID_KEY]) for sample in samples})
    assert all((index - 10 - 2) % 4 in (0, 1) and index >= 12 for index in ids), ids
    assert stats.samples == 12 and stats.tasks_held <= 3 and stats.tasks_received >= 4
    assert stats.distinct_tasks_used == len(ids) and stats.max_uses >= stats.mean_uses == 12 / len(ids)
    assert stats.next_task > max(ids) and (stats.next_task - 10) % 4 == 0 and stats.skipped == 0
    reference = encode_task(PseudoTaskStream(stream_config()).render_tasks([ids[0]])[0], source.build(), 8)
    sample = next(s for s in samples if int(s[CONTEXT_ID_KEY]) == ids[0])
    assert np.array_equal(sample[CONTEXT_SCENE_FEATURES_KEY].numpy(), reference.scene_features)
    assert np.array_equal(sample[CONTEXT_SCENE_POSITIONS_KEY].numpy(), reference.scene_positions)
    assert any(np.array_equal(sample[SCENE_FEATURES_KEY].numpy(), live) for live in reference.live_features)


def test_tasks_that_cannot_be_planned_are_skipped_and_counted():
    """With L = 40 most ``reach`` tasks of seed 11 have context demonstrations too short (the stream's own case)."""
    config = PoolConfig(stream=stream_config(generation=GenerationConfig(seed=11, family="reach"), num_waypoints=40),
                        capacity=2, min_tasks=2)
    pool = TaskPool(config, EncoderSource(encoder_preset("small"), weights=str(WEIGHTS)))
    try:
        list(itertools.islice(pool, 2))
        stats = pool.stats()
    finally:
        pool.close()
    assert stats.skipped > 0 and stats.tasks_received >= 2


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"capacity": 0}, "capacity must be a positive integer"),
        ({"capacity": 4, "min_tasks": 5}, "must not exceed capacity"),
        ({"generators": 1.5}, "generators must be a positive integer"),
        ({"device": "mps"}, "device must be 'cpu' or 'cuda'"),
    ],
)
def test_bad_pool_settings_are_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=message):
        PoolConfig(stream=stream_config(), **overrides)


def test_the_encoder_must_be_one_the_generators_can_rebuild(tmp_path):
    with pytest.raises(ValueError, match="give a checkpoint"):
        frozen_encoder(encoder_preset("small"))
    with pytest.raises(ValueError, match="does not fit"):
        frozen_encoder(encoder_preset("paper"), checkpoint=SHIPPED)
    with pytest.raises(ValueError, match="rank must be an integer"):
        TaskPool(PoolConfig(stream=stream_config()), EncoderSource(encoder_preset("small"), weights=str(WEIGHTS)),
                 rank=2, world_size=2)
    policy_config = InstantPolicyConfig(device="cpu", pretrained_encoder=False)
    cfg = SimpleNamespace(policy=policy_config, resume=False, checkpoint_path=None, num_workers=0, seed=1, steps=2,
                          batch_size=2, output_dir=tmp_path)
    with pytest.raises(ValueError, match="a random encoder cannot be rebuilt"):
        make_stream_datasets(cfg, stream_config(), 0, 1, PoolConfig(stream=stream_config()))
    with pytest.raises(ValueError, match="--num_workers=0"):
        make_stream_datasets(SimpleNamespace(**{**vars(cfg), "num_workers": 2}), stream_config(), 0, 1,
                             PoolConfig(stream=stream_config()))


def test_the_pool_refuses_to_be_copied_into_data_loader_workers():
    pool = TaskPool(PoolConfig(stream=stream_config()), EncoderSource(encoder_preset("small"), weights=str(WEIGHTS)))
    loader = torch.utils.data.DataLoader(pool, batch_size=2, num_workers=1)
    with pytest.raises(RuntimeError, match="num_workers=0"):
        next(iter(loader))


def test_generators_exit_when_the_training_process_is_killed(tmp_path):
    """A training process killed at once (``kill -9``, a lost machine) leaves no generator behind, even one blocked
    on a full queue."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = tmp_path / "train.py"
    script.write_text(f"""
import itertools, sys, time
from lerobot_instant_policy.model.geometry_encoder import encoder_preset
from lerobot_instant_policy.training.task_pool import EncoderSource, PoolConfig, TaskPool
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig
from lerobot_instant_policy.pseudo_demos.stream import StreamConfig

if __name__ == "__main__":
    stream = StreamConfig(generation=GenerationConfig(seed=11), samples_per_task=2, tasks_per_render=1,
                          surface_samples=1024, zbuffer_resolution=(160, 120))
    pool = TaskPool(PoolConfig(stream=stream, capacity=1, min_tasks=1, queue_size=1),
                    EncoderSource(encoder_preset("small"), weights={str(WEIGHTS)!r}))
    next(iter(pool))
    print(" ".join(str(process.pid) for process in pool._processes), flush=True)
    time.sleep(600)
""")
    child = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=os.getcwd(),
                             env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        generators = [int(pid) for pid in child.stdout.readline().split()]
        assert generators
        time.sleep(3)  # the generator fills the queue and blocks in put()
        child.send_signal(signal.SIGKILL)
        child.wait()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(os.path.exists(f"/proc/{pid}") for pid in generators):
            time.sleep(0.5)
        assert not any(os.path.exists(f"/proc/{pid}") for pid in generators)
    finally:
        child.kill()
