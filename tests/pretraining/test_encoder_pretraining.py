"""Occupancy pretraining: data labels, loss falling, resume, the shipped weights and the CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

import lerobot_instant_policy
from lerobot_instant_policy.cli.pretrain_encoder import main as pretrain_main
from lerobot_instant_policy.model.geometry_encoder import encoder_preset
from lerobot_instant_policy.model.occupancy import OccupancyNetwork, load_geometry_encoder, sidecar_path
from lerobot_instant_policy.pretraining import encoder_pretraining
from lerobot_instant_policy.pretraining.encoder_pretraining import PretrainConfig, pretrain, resume_path
from lerobot_instant_policy.pretraining.occupancy_data import OccupancyDataConfig, generate_occupancy_set

SHIPPED = Path(lerobot_instant_policy.__file__).parent / "assets" / "encoder" / "small.safetensors"
SMALL_DATA = OccupancyDataConfig(num_queries=256, dense_samples=4096)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("occupancy_cache")


def _config(cache_dir, **overrides) -> PretrainConfig:
    values = dict(
        steps=6,
        batch_size=2,
        queries_per_cloud=128,
        train_scenes=6,
        eval_scenes=3,
        warmup_steps=2,
        cache_dir=str(cache_dir),
        checkpoint_every=3,
        data=SMALL_DATA,
    )
    return PretrainConfig(**{**values, **overrides})


def test_scene_stream_does_not_depend_on_chunking():
    whole = generate_occupancy_set(3, 7, "train", SMALL_DATA)
    tail = generate_occupancy_set(1, 7, "train", SMALL_DATA, start=2)
    assert np.array_equal(whole.points[2], tail.points[0]) and np.array_equal(whole.labels[2], tail.labels[0])
    assert whole.points.shape == (3, 2048, 3) and whole.queries.shape == (3, 256, 3) and whole.labels.dtype == bool


def test_rendered_points_lie_on_the_labelled_surface():
    exact = OccupancyDataConfig(
        num_queries=400, dense_samples=16384, surface_noise=0.0, surface_fraction=1.0, near_fraction=0.0
    )
    data = generate_occupancy_set(2, 3, "held_out", exact)
    assert data.labels.mean() > 0.99
    mixed = generate_occupancy_set(2, 3, "held_out", OccupancyDataConfig(num_queries=400))
    assert 0.3 < mixed.labels.mean() < 0.7


def test_loss_falls_when_fitting_scenes(cache_dir):
    config = _config(cache_dir, batch_size=4, queries_per_cloud=256)
    train_set, _ = encoder_pretraining.load_sets(config)
    torch.manual_seed(0)
    network = OccupancyNetwork.from_preset("small")
    optimizer = torch.optim.AdamW(network.parameters(), lr=1e-3)
    generator, rng = torch.Generator().manual_seed(0), np.random.default_rng(0)
    steps = [encoder_pretraining._train_step(network, optimizer, train_set, config, generator, rng) for _ in range(80)]
    losses = [loss for loss, _ in steps]
    assert np.mean(losses[-10:]) < 0.85 * np.mean(losses[:10])
    assert np.mean([metrics["balanced_accuracy"] for _, metrics in steps[-10:]]) > 0.7


def test_interrupted_run_resumes_to_the_same_weights(cache_dir, tmp_path, monkeypatch):
    config = _config(cache_dir)
    reference = pretrain(config, tmp_path / "reference.safetensors", progress=False)
    calls = {"n": 0}
    real_step = encoder_pretraining._train_step

    def crash_after_four(*args):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real_step(*args)

    monkeypatch.setattr(encoder_pretraining, "_train_step", crash_after_four)
    out = tmp_path / "resumed.safetensors"
    with pytest.raises(KeyboardInterrupt):
        pretrain(config, out, progress=False)
    assert torch.load(resume_path(out), weights_only=True)["step"] == 3
    calls["n"] = -100
    resumed = pretrain(config, out, progress=False)
    assert calls["n"] == -97
    assert resumed["held_out"] == reference["held_out"]
    a = load_geometry_encoder(out).state_dict()
    b = load_geometry_encoder(tmp_path / "reference.safetensors").state_dict()
    assert all(torch.equal(a[key], b[key]) for key in a)
    with pytest.raises(ValueError, match="other settings"):
        pretrain(_config(cache_dir, lr=5e-4), out, progress=False)


def test_shipped_weights_load_as_the_small_preset():
    encoder = load_geometry_encoder(SHIPPED, expected=encoder_preset("small"))
    assert SHIPPED.stat().st_size < 5_000_000
    sidecar = json.loads(sidecar_path(SHIPPED).read_text())
    assert sidecar["metrics"]["held_out"]["balanced_accuracy"] >= 0.9
    assert sidecar["pretraining"]["train_seconds"] > 0
    with pytest.raises(ValueError, match="does not match"):
        load_geometry_encoder(SHIPPED, expected=encoder_preset("paper"))
    positions, features = encoder(torch.randn(1, 2048, 3) * 0.05)
    assert positions.shape == (1, 16, 3) and features.shape == (1, 16, encoder_preset("small").feature_dim)


def test_eval_cli_reaches_the_target_on_held_out_objects(cache_dir, capsys):
    code = pretrain_main(
        ["--eval", str(SHIPPED), "--eval-scenes", "24", "--cache-dir", str(cache_dir), "--preset", "small"]
    )
    assert code == 0
    metrics = json.loads(capsys.readouterr().out)
    assert metrics["num_scenes"] == 24 and metrics["split"] == "held_out"
    assert metrics["balanced_accuracy"] >= 0.9
    assert 0 < metrics["iou"] <= 1


def test_eval_cli_refuses_another_preset(capsys):
    assert pretrain_main(["--eval", str(SHIPPED), "--preset", "paper"]) == 2
    assert "does not match" in capsys.readouterr().err


def test_show_draws_the_decoded_surface(tmp_path, capsys):
    png = tmp_path / "bunny.png"
    assert pretrain_main(["--show", str(SHIPPED), "--object", "pb/bunny", "--png", str(png)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert summary["decoded_points"] > 100 and summary["balanced_accuracy"] > 0.8
    assert pretrain_main(["--show", str(SHIPPED), "--object", "nope/0", "--png", str(png)]) == 2
