"""The data contract's codec (``contract``): 8-vectors (xyz, quaternion xyzw with ``w ≥ 0``, gripper) ↔ ``T_world_ee``
and the gripper, the same in numpy and in torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.contract import (
    POSE_GRIPPER_NAMES,
    POSE_GRIPPER_SHAPE,
    poses_from_vectors,
    poses_from_vectors_torch,
    vectors_from_poses,
    vectors_from_poses_torch,
)


def _random_vectors(batch: tuple[int, ...], seed: int = 0) -> np.ndarray:
    """``(*batch, 8)`` float64 vectors: random positions, unit quaternions (either sign of ``w``), 0/1 grippers."""
    rng = np.random.default_rng(seed)
    count = int(np.prod(batch))
    quaternions = Rotation.random(count, random_state=seed).as_quat() * rng.choice([-1.0, 1.0], (count, 1))
    vectors = np.concatenate(
        [rng.uniform(-1.0, 1.0, (count, 3)), quaternions, rng.integers(0, 2, (count, 1)).astype(np.float64)], axis=1
    )
    return vectors.reshape(*batch, 8)


def test_the_vector_has_eight_named_entries():
    assert POSE_GRIPPER_SHAPE == (8,) and len(POSE_GRIPPER_NAMES) == 8
    assert POSE_GRIPPER_NAMES[3:7] == ["qx", "qy", "qz", "qw"] and POSE_GRIPPER_NAMES[7] == "gripper_open"


@pytest.mark.parametrize("batch", [(), (5,), (3, 4)])
def test_numpy_decode_encode_is_the_identity_with_w_non_negative(batch):
    vectors = _random_vectors(batch)
    T_world_ee, gripper_open = poses_from_vectors(vectors)
    assert T_world_ee.shape == (*batch, 4, 4) and T_world_ee.dtype == np.float64
    assert gripper_open.shape == batch
    np.testing.assert_allclose(T_world_ee[..., :3, 3], vectors[..., :3])
    np.testing.assert_allclose(T_world_ee[..., 3, :], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (*batch, 4)))
    encoded = vectors_from_poses(T_world_ee, gripper_open)
    assert encoded.shape == (*batch, 8)
    assert (encoded[..., 6] >= 0).all()
    canonical = np.where(vectors[..., 6:7] < 0, -vectors[..., 3:7], vectors[..., 3:7])
    np.testing.assert_allclose(encoded[..., 3:7], canonical, atol=1e-12)
    np.testing.assert_array_equal(encoded[..., :3], vectors[..., :3])
    np.testing.assert_array_equal(encoded[..., 7], vectors[..., 7])


@pytest.mark.parametrize("batch", [(), (5,), (3, 4)])
def test_torch_decode_encode_is_the_identity_with_w_non_negative(batch):
    vectors = torch.from_numpy(_random_vectors(batch))
    T_world_ee, gripper_open = poses_from_vectors_torch(vectors)
    assert T_world_ee.shape == (*batch, 4, 4) and T_world_ee.dtype == torch.float64
    assert gripper_open.shape == batch
    encoded = vectors_from_poses_torch(T_world_ee, gripper_open)
    assert encoded.shape == (*batch, 8) and (encoded[..., 6] >= 0).all()
    canonical = torch.where(vectors[..., 6:7] < 0, -vectors[..., 3:7], vectors[..., 3:7])
    torch.testing.assert_close(encoded[..., 3:7], canonical, rtol=0, atol=1e-12)
    torch.testing.assert_close(encoded[..., [0, 1, 2, 7]], vectors[..., [0, 1, 2, 7]], rtol=0, atol=0)


def test_numpy_and_torch_codecs_agree():
    vectors = _random_vectors((6, 3), seed=1)
    T_numpy, gripper_numpy = poses_from_vectors(vectors)
    T_torch, gripper_torch = poses_from_vectors_torch(torch.from_numpy(vectors))
    np.testing.assert_allclose(T_torch.numpy(), T_numpy, atol=1e-12)
    np.testing.assert_array_equal(gripper_torch.numpy(), gripper_numpy)
    np.testing.assert_allclose(
        vectors_from_poses_torch(T_torch, gripper_torch).numpy(), vectors_from_poses(T_numpy, gripper_numpy), atol=1e-12
    )


def test_float32_torch_vectors_stay_float32():
    vectors = torch.from_numpy(_random_vectors((4,), seed=2)).float()
    T_world_ee, gripper_open = poses_from_vectors_torch(vectors)
    assert T_world_ee.dtype == torch.float32 and gripper_open.dtype == torch.float32
    assert vectors_from_poses_torch(T_world_ee, gripper_open).dtype == torch.float32


@pytest.mark.parametrize("factor", [-1.0, 3.0, -0.5])
def test_a_quaternion_decodes_to_the_same_pose_whatever_its_sign_and_norm(factor):
    vectors = _random_vectors((8,), seed=3)
    scaled = vectors.copy()
    scaled[:, 3:7] *= factor
    np.testing.assert_allclose(poses_from_vectors(scaled)[0], poses_from_vectors(vectors)[0], atol=1e-12)
    torch.testing.assert_close(
        poses_from_vectors_torch(torch.from_numpy(scaled))[0], poses_from_vectors_torch(torch.from_numpy(vectors))[0],
        rtol=0, atol=1e-12,
    )


def test_a_single_gripper_flag_encodes_one_pose():
    T_world_ee, _ = poses_from_vectors(_random_vectors((1,), seed=5)[0])
    assert vectors_from_poses(T_world_ee, True)[7] == 1.0 and vectors_from_poses(T_world_ee, False)[7] == 0.0


def test_a_zero_quaternion_raises_a_clear_value_error():
    vectors = _random_vectors((3,), seed=6)
    vectors[1, 3:7] = 0.0
    with pytest.raises(ValueError, match="zero quaternion"):
        poses_from_vectors(vectors)
    with pytest.raises(ValueError, match="zero quaternion"):
        poses_from_vectors_torch(torch.from_numpy(vectors))


def test_vectors_of_the_wrong_width_are_refused():
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\)"):
        poses_from_vectors(np.zeros((2, 7)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\)"):
        poses_from_vectors_torch(torch.zeros(2, 7))
