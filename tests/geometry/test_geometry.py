"""Rigid transforms (``geometry.se3``) and fixed-size point-cloud resampling (``geometry.sampling``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from synthetic_demos import random_poses

from lerobot_instant_policy.geometry.sampling import resample_indices, resample_points
from lerobot_instant_policy.geometry.se3 import (
    invert,
    look_rotation,
    make_pose,
    pose_distance,
    pose_from_pos_quat,
    pose_to_pos_quat,
    rotation_angle,
    transform_points,
)

# --------------------------------------------------------------------------------------------- se3


def test_invert_composes_to_identity_single_and_batched():
    poses = random_poses(16)
    for pose in poses:
        np.testing.assert_allclose(invert(pose) @ pose, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(pose @ invert(pose), np.eye(4), atol=1e-12)
    batched = invert(poses)
    assert batched.shape == poses.shape
    np.testing.assert_allclose(batched @ poses, np.broadcast_to(np.eye(4), poses.shape), atol=1e-12)
    np.testing.assert_allclose(batched, np.linalg.inv(poses), atol=1e-12)


def test_invert_undoes_transform_points():
    pose = random_poses(1, seed=3)[0]
    points = np.random.default_rng(3).normal(size=(50, 3))
    moved = transform_points(pose, points)
    assert not np.allclose(moved, points)
    np.testing.assert_allclose(transform_points(invert(pose), moved), points, atol=1e-12)


def test_pos_quat_round_trip_and_non_negative_w():
    for pose in random_poses(32, seed=1):
        position, quat = pose_to_pos_quat(pose)
        assert quat[3] >= 0.0
        assert np.isclose(np.linalg.norm(quat), 1.0)
        np.testing.assert_allclose(pose_from_pos_quat(position, quat), pose, atol=1e-12)


def test_pos_quat_canonicalises_negative_w():
    quat = np.array([0.3, -0.5, 0.1, -0.8])
    quat /= np.linalg.norm(quat)
    pose = pose_from_pos_quat([1.0, 2.0, 3.0], quat)
    position, back = pose_to_pos_quat(pose)
    np.testing.assert_allclose(position, [1.0, 2.0, 3.0])
    assert back[3] > 0.0
    np.testing.assert_allclose(back, -quat, atol=1e-12)  # the same rotation, the other hemisphere
    # pose_to_pos_quat returns a copy: mutating it must not mutate the pose
    position[0] = 99.0
    assert pose[0, 3] == 1.0


def test_rotation_angle_matches_scipy_magnitude():
    rotations_a = Rotation.random(64, random_state=4)
    rotations_b = Rotation.random(64, random_state=5)
    expected = (rotations_a.inv() * rotations_b).magnitude()
    got = rotation_angle(rotations_a.as_matrix(), rotations_b.as_matrix())
    np.testing.assert_allclose(got, expected, atol=1e-6)
    # edge cases: identical, tiny and half-turn differences
    base = rotations_a[0]
    for angle in (0.0, 1e-3, np.deg2rad(3.0), np.pi / 2, np.pi - 1e-4, np.pi):
        other = base * Rotation.from_rotvec(np.array([0.2, -0.4, 0.9]) / np.linalg.norm([0.2, -0.4, 0.9]) * angle)
        assert rotation_angle(base.as_matrix(), other.as_matrix()) == pytest.approx(angle, abs=2e-4)


def test_pose_distance_translation_and_rotation():
    a = make_pose([0.0, 0.0, 0.0])
    b = make_pose([0.03, 0.04, 0.0], Rotation.from_euler("z", 0.25))
    translation, rotation = pose_distance(a, b)
    assert translation == pytest.approx(0.05)
    assert rotation == pytest.approx(0.25)


@pytest.mark.parametrize(
    "approach",
    [
        [0.0, 0.0, -1.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],  # parallel to the first helper axis
        [-0.95, 0.1, 0.2],
        [0.3, -0.7, -0.5],
        [0.0, 2.0, 0.0],  # not normalised
    ],
)
@pytest.mark.parametrize("yaw", [0.0, 1.1, -2.8])
def test_look_rotation_is_proper_with_z_along_approach(approach, yaw):
    approach = np.asarray(approach, dtype=float)
    rotation = look_rotation(approach, yaw)
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation[:, 2], approach / np.linalg.norm(approach), atol=1e-12)


def test_look_rotation_yaw_turns_about_the_approach():
    approach = np.array([0.2, 0.1, -1.0])
    base = look_rotation(approach, 0.0)
    turned = look_rotation(approach, 0.7)
    # same z-axis, x-axis turned by exactly the yaw (right-handed about z)
    np.testing.assert_allclose(turned[:, 2], base[:, 2], atol=1e-12)
    relative = base.T @ turned
    np.testing.assert_allclose(relative, Rotation.from_euler("z", 0.7).as_matrix(), atol=1e-12)


# ---------------------------------------------------------------------------------------- sampling


def test_resample_indices_fps_picks_distinct_points():
    points = np.random.default_rng(0).uniform(-1, 1, size=(500, 3))
    indices = resample_indices(points, 64, np.random.default_rng(1))
    assert indices.shape == (64,)
    assert len(np.unique(indices)) == 64
    assert indices.min() >= 0 and indices.max() < 500


def test_resample_indices_fps_covers_separated_clusters():
    """Farthest-point sampling (not a random subset): with 2 points out of 2 far clusters, one from each."""
    rng = np.random.default_rng(2)
    cluster_a = rng.normal(scale=0.01, size=(900, 3))
    cluster_b = rng.normal(scale=0.01, size=(100, 3)) + [5.0, 0.0, 0.0]
    points = np.concatenate([cluster_a, cluster_b])
    for seed in range(5):
        indices = resample_indices(points, 2, np.random.default_rng(seed))
        assert sorted(indices >= 900) == [False, True]


def test_resample_indices_pads_with_repeats():
    points = np.random.default_rng(0).normal(size=(10, 3))
    indices = resample_indices(points, 37, np.random.default_rng(0))
    assert indices.shape == (37,)
    assert set(indices.tolist()) == set(range(10))  # every original point kept
    assert indices.min() >= 0 and indices.max() < 10


def test_resample_indices_exact_count_is_identity():
    points = np.random.default_rng(0).normal(size=(20, 3))
    np.testing.assert_array_equal(resample_indices(points, 20, np.random.default_rng(0)), np.arange(20))


@pytest.mark.parametrize("count", [5, 300])
def test_resample_indices_deterministic_for_seed(count):
    points = np.random.default_rng(7).normal(size=(count, 3))
    first = resample_indices(points, 50, np.random.default_rng(11))
    second = resample_indices(points, 50, np.random.default_rng(11))
    np.testing.assert_array_equal(first, second)


def test_resample_points_returns_selected_float32():
    points = np.random.default_rng(0).normal(size=(100, 3))
    out = resample_points(points, 16, np.random.default_rng(0))
    assert out.shape == (16, 3) and out.dtype == np.float32
    # each output row is one of the input points
    distances = np.linalg.norm(points[None].astype(np.float32) - out[:, None], axis=2).min(axis=1)
    assert distances.max() < 1e-6


def test_resample_indices_rejects_empty_cloud():
    with pytest.raises(ValueError, match="empty"):
        resample_indices(np.zeros((0, 3)), 8, np.random.default_rng(0))


@pytest.mark.parametrize("shape", [(10, 2), (10,), (2, 10, 3)])
def test_resample_indices_rejects_wrong_shape(shape):
    with pytest.raises(ValueError, match=r"shape \(P, 3\)"):
        resample_indices(np.zeros(shape), 8, np.random.default_rng(0))


def test_mean_rigid_averages_translations_and_rotations_and_commutes_with_a_common_motion():
    """``mean_rigid``: the mean of copies is the pose itself; of two rotations ±θ about one axis, the identity; the
    mean translation; a valid rotation; and moving every pose by one rigid G moves the mean by G (so averaging in the
    EE frame and then composing with the EE pose gives the same as averaging world-frame poses)."""
    import torch

    from lerobot_instant_policy.geometry.rigid_torch import compose, make_rigid, mean_rigid

    rng = np.random.default_rng(0)

    def rigid(rotvec, translation):
        return make_rigid(torch.tensor(Rotation.from_rotvec(rotvec).as_matrix()), torch.tensor(translation))

    pose = rigid([0.3, -0.2, 0.9], [0.1, 0.2, 0.3])
    torch.testing.assert_close(mean_rigid(pose.expand(3, 4, 4), dim=0), pose)
    pair = torch.stack([rigid([0.0, 0.0, 0.4], [0.0, 0.0, 0.0]), rigid([0.0, 0.0, -0.4], [0.2, 0.4, 0.0])])
    torch.testing.assert_close(mean_rigid(pair, dim=0), rigid([0.0, 0.0, 0.0], [0.1, 0.2, 0.0]))
    samples = torch.stack([rigid(rng.normal(0, 0.3, 3), rng.normal(0, 0.05, 3)) for _ in range(12)]).reshape(2, 6, 4, 4)
    mean = mean_rigid(samples, dim=1)
    assert mean.shape == (2, 4, 4)
    torch.testing.assert_close(mean[..., :3, :3] @ mean[..., :3, :3].transpose(-1, -2), torch.eye(3).expand(2, 3, 3).double())
    assert torch.all(torch.det(mean[..., :3, :3]) > 0)
    G = rigid([1.0, 2.0, -0.5], [0.4, -0.3, 0.2])
    torch.testing.assert_close(mean_rigid(compose(G, samples), dim=1), compose(G, mean))
