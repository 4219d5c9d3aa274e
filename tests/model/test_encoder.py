"""Geometry encoder: point ops against brute force, invariances, batching, input errors, weights files."""

import json

import numpy as np
import pytest
import torch

from lerobot_instant_policy.model.geometry_encoder import (
    ENCODER_PRESETS,
    GeometryEncoder,
    GeometryEncoderConfig,
    encoder_preset,
)
from lerobot_instant_policy.model.occupancy import (
    OccupancyNetwork,
    load_geometry_encoder,
    load_occupancy_network,
    save_occupancy_network,
    sidecar_path,
)
from lerobot_instant_policy.model.point_ops import farthest_point_sampling, group_max, nearest_centroid

TINY = GeometryEncoderConfig(num_centroids=(32, 8), layer_widths=((16, 32), (32, 48)), num_frequencies=6)


def _clouds(batch: int, points: int = 512, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.randn(batch, points, 3, generator=generator) * 0.08 + torch.tensor([0.5, 0.0, 0.1])


def _brute_force_fps(points: np.ndarray, num_samples: int, start: int) -> list[int]:
    chosen = [start]
    while len(chosen) < num_samples:
        best, best_distance = None, -1.0
        for index in range(len(points)):
            distance = min(np.linalg.norm(points[index] - points[c]) for c in chosen)
            if distance > best_distance:
                best, best_distance = index, distance
        chosen.append(best)
    return chosen


def test_fps_matches_brute_force_reference():
    rng = np.random.default_rng(3)
    clouds = rng.normal(size=(3, 40, 3))
    indices = farthest_point_sampling(torch.from_numpy(clouds), 12)
    for cloud, chosen in zip(clouds, indices.tolist()):
        start = int(np.argmax(np.linalg.norm(cloud - cloud.mean(axis=0), axis=1)))
        assert chosen == _brute_force_fps(cloud, 12, start)


def test_fast_cpu_fps_equals_the_torch_loop():
    from lerobot_instant_policy.model.point_ops import farthest_point_sampling_torch

    clouds = _clouds(3, 2048)
    start = (clouds - clouds.mean(dim=1, keepdim=True)).square().sum(-1).argmax(dim=1)
    assert torch.equal(farthest_point_sampling(clouds, 256), farthest_point_sampling_torch(clouds, 256, start))


def test_fps_random_start_is_seeded_and_spreads_points():
    clouds = _clouds(2, 200)
    first = farthest_point_sampling(clouds, 16, torch.Generator().manual_seed(5))
    again = farthest_point_sampling(clouds, 16, torch.Generator().manual_seed(5))
    assert torch.equal(first, again)
    starts = {int(farthest_point_sampling(clouds, 4, torch.Generator().manual_seed(s))[0, 0]) for s in range(8)}
    assert len(starts) > 1
    assert all(len(set(row)) == 16 for row in first.tolist())
    with pytest.raises(ValueError, match="cannot sample"):
        farthest_point_sampling(clouds, 201)


def test_nearest_centroid_and_group_max_match_loops():
    points, centroids = _clouds(2, 100), _clouds(2, 7, seed=1)
    groups = nearest_centroid(points, centroids)
    for b in range(2):
        for p in range(100):
            assert groups[b, p] == torch.linalg.norm(centroids[b] - points[b, p], dim=-1).argmin()
    values = torch.randn(2, 100, 5)
    pooled = group_max(values, groups, 7)
    for b in range(2):
        for g in range(7):
            members = values[b, groups[b] == g]
            expected = members.max(dim=0).values if len(members) else torch.zeros(5)
            assert torch.allclose(pooled[b, g], expected)


def test_output_shapes_and_presets():
    encoder = GeometryEncoder(TINY)
    positions, features = encoder(_clouds(2))
    assert positions.shape == (2, 8, 3) and features.shape == (2, 8, 48)
    assert positions.dtype == features.dtype == torch.float32
    assert encoder_preset("paper").num_centroids == (256, 16) and encoder_preset("paper").feature_dim == 512
    assert encoder_preset("small").num_nodes == 16
    with pytest.raises(ValueError, match="unknown encoder preset"):
        encoder_preset("huge")


def test_centroids_are_input_points():
    clouds = _clouds(2)
    positions, _ = GeometryEncoder(TINY)(clouds)
    for cloud, nodes in zip(clouds, positions):
        assert torch.cdist(nodes, cloud, compute_mode="donot_use_mm_for_euclid_dist").min(dim=1).values.max() == 0


@pytest.mark.parametrize("preset", ["tiny", "small"])
def test_invariant_to_point_order(preset):
    torch.manual_seed(0)
    encoder = GeometryEncoder(TINY if preset == "tiny" else ENCODER_PRESETS["small"]).eval()
    clouds = _clouds(2, 2048)
    permuted = clouds[:, torch.randperm(2048)]
    with torch.no_grad():
        positions, features = encoder(clouds)
        positions_p, features_p = encoder(permuted)
    assert torch.equal(positions, positions_p)
    assert torch.allclose(features, features_p, atol=1e-5)


def test_batched_and_single_agree():
    torch.manual_seed(0)
    encoder = GeometryEncoder(ENCODER_PRESETS["small"]).eval()
    clouds = _clouds(3, 2048)
    with torch.no_grad():
        positions, features = encoder(clouds)
        for index in range(3):
            single_positions, single_features = encoder(clouds[index : index + 1])
            assert torch.equal(single_positions[0], positions[index])
            assert torch.allclose(single_features[0], features[index], atol=1e-5)


def test_translation_moves_centroids_and_keeps_features():
    torch.manual_seed(0)
    encoder = GeometryEncoder(ENCODER_PRESETS["small"]).eval()
    clouds = _clouds(2, 2048).double()
    encoder = encoder.double()
    shift = torch.tensor([0.31, -0.42, 0.17], dtype=torch.float64)
    with torch.no_grad():
        positions, features = encoder(clouds)
        moved_positions, moved_features = encoder(clouds + shift)
    assert torch.allclose(moved_positions, positions + shift, atol=1e-9)
    assert torch.allclose(moved_features, features, atol=1e-6)


def test_features_depend_on_geometry():
    torch.manual_seed(0)
    encoder = GeometryEncoder(TINY).eval()
    clouds = _clouds(1)
    stretched = clouds * torch.tensor([1.0, 1.0, 2.0])
    with torch.no_grad():
        assert not torch.allclose(encoder(clouds)[1], encoder(stretched)[1], atol=1e-3)


@pytest.mark.parametrize(
    "points, message",
    [
        (torch.zeros(1, 16, 3), "16 points but the encoder samples 32"),
        (torch.zeros(2, 512, 2), r"shape \(B, P, 3\)"),
        (torch.zeros(512, 3), r"shape \(B, P, 3\)"),
        (torch.zeros(1, 512, 3, dtype=torch.int64), "floating-point"),
        (np.zeros((1, 512, 3), dtype=np.float32), r"shape \(B, P, 3\)"),
    ],
)
def test_bad_input_is_refused(points, message):
    with pytest.raises(ValueError, match=message):
        GeometryEncoder(TINY)(points)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_points_are_refused(bad):
    clouds = _clouds(2)
    clouds[1, 17, 2] = bad
    with pytest.raises(ValueError, match="NaN or inf"):
        GeometryEncoder(TINY)(clouds)


def test_invalid_config_is_refused():
    with pytest.raises(ValueError, match="non-increasing"):
        GeometryEncoderConfig(num_centroids=(16, 32), layer_widths=((8,), (8,)))
    with pytest.raises(ValueError, match="one entry per"):
        GeometryEncoderConfig(num_centroids=(16,), layer_widths=((8,), (8,)))
    with pytest.raises(ValueError, match="unknown GeometryEncoderConfig keys"):
        GeometryEncoderConfig.from_dict({"num_centroids": [16], "layer_widths": [[8]], "depth": 3})


def test_save_load_round_trip(tmp_path):
    torch.manual_seed(0)
    network = OccupancyNetwork(TINY, OccupancyNetwork.from_preset("small").decoder.config)
    path = tmp_path / "tiny.safetensors"
    save_occupancy_network(network, path, metrics={"held_out": {"balanced_accuracy": 0.5}})
    clouds, queries = _clouds(2), _clouds(2, 64, seed=4)
    loaded = load_occupancy_network(path, expected=TINY)
    encoder = load_geometry_encoder(path, expected=TINY)
    with torch.no_grad():
        assert torch.equal(loaded(clouds, queries), network(clouds, queries))
        assert torch.equal(encoder(clouds)[1], network.encoder(clouds)[1])
    assert json.loads(sidecar_path(path).read_text())["metrics"]["held_out"]["balanced_accuracy"] == 0.5


def test_loading_refuses_mismatches(tmp_path):
    path = tmp_path / "tiny.safetensors"
    save_occupancy_network(OccupancyNetwork(TINY, OccupancyNetwork.from_preset("small").decoder.config), path)
    with pytest.raises(ValueError, match="does not match the requested"):
        load_geometry_encoder(path, expected=encoder_preset("small"))
    sidecar = json.loads(sidecar_path(path).read_text())
    sidecar["encoder"]["layer_widths"] = [[16, 32], [32, 64]]
    sidecar_path(path).write_text(json.dumps(sidecar))
    with pytest.raises(ValueError, match="do not match the config"):
        load_geometry_encoder(path)
    sidecar_path(path).unlink()
    with pytest.raises(FileNotFoundError, match="no config file"):
        load_occupancy_network(path)
    with pytest.raises(FileNotFoundError, match="no weights file"):
        load_geometry_encoder(tmp_path / "missing.safetensors")
