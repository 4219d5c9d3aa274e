"""A human hand as the gripper (``perception.hand``) and removed from the clouds (``perception.hand_mask``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lerobot.configs import PipelineFeatureType
from lerobot.processor import PolicyProcessorPipeline
from scipy.spatial.transform import Rotation
from synthetic_demos import random_poses

from lerobot_instant_policy.contract import POINTCLOUD_KEY, STATE_KEY, poses_from_vectors
from lerobot_instant_policy.geometry.se3 import make_pose, pose_distance, transform_points
from lerobot_instant_policy.perception.hand import (
    HAND_LANDMARKS_KEY,
    HAND_VALID_KEY,
    HandGapError,
    HandMappingConfig,
    HandToGripperStateStep,
    landmarks_from_gripper,
    lift_image_landmarks,
    map_hand_to_gripper,
)
from lerobot_instant_policy.perception.hand_mask import (
    HAND_BONES,
    HAND_MASK_KEY,
    ClearHandPixelsStep,
    MaskHandPointsStep,
    mask_hand_points,
)
from lerobot_instant_policy.perception.steps import CLOUD_MASK_KEY


def smooth_poses(count: int) -> np.ndarray:
    """A gripper sweeping 30 cm while turning 90° about its approach axis: ``(count, 4, 4)``."""
    turn = Rotation.from_euler("z", np.linspace(0, 90, count)[:, None], degrees=True)
    down = Rotation.from_euler("x", 180, degrees=True)
    return np.stack([make_pose(np.array([0.4 + 0.3 * s, 0.0, 0.2]), down * r) for s, r in
                     zip(np.linspace(0, 1, count), turn, strict=True)])


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="close_below_m < open_above_m"):
        HandMappingConfig(close_below_m=0.05, open_above_m=0.04)
    with pytest.raises(ValueError, match="palm_landmarks"):
        HandMappingConfig(palm_landmarks=(0, 8))
    with pytest.raises(ValueError, match="position_smoothing"):
        HandMappingConfig(position_smoothing=1.0)
    with pytest.raises(ValueError, match="max_gap_frames"):
        HandMappingConfig(max_gap_frames=-1)
    with pytest.raises(ValueError, match="gripper_hold_frames"):
        HandMappingConfig(gripper_hold_frames=0)


def test_round_trip_recovers_the_gripper_pose_and_is_proper():
    T_world_ee = random_poses(40, extent_m=0.5)
    apertures = np.linspace(0.06, 0.09, 40)  # all open: no hysteresis in the way
    trajectory = map_hand_to_gripper(landmarks_from_gripper(T_world_ee, apertures))
    translation, angle = pose_distance(trajectory.T_world_ee, T_world_ee)
    assert translation.max() < 1e-9 and np.degrees(angle).max() < 1e-6
    np.testing.assert_allclose(np.linalg.det(trajectory.T_world_ee[:, :3, :3]), 1.0, atol=1e-9)
    assert trajectory.valid.all() and (trajectory.gripper_open == 1.0).all()
    vectors = trajectory.state_vectors()
    assert vectors.shape == (40, 8)
    np.testing.assert_allclose(poses_from_vectors(vectors)[0], T_world_ee, atol=1e-9)


def test_round_trip_under_one_centimetre_landmark_noise():
    T_world_ee = random_poses(200, seed=3, extent_m=0.5)
    noisy = landmarks_from_gripper(T_world_ee, 0.07, np.random.default_rng(1), noise_m=0.01)
    trajectory = map_hand_to_gripper(noisy, HandMappingConfig(max_gap_frames=200))
    translation, angle = pose_distance(trajectory.T_world_ee[trajectory.valid], T_world_ee[trajectory.valid])
    # Measured: median 1.1 cm (the midpoint of two noisy tips) and 17° (the 7 cm thumb-index axis).
    assert np.median(translation) < 0.015 and np.degrees(np.median(angle)) < 25


def test_a_centred_window_divides_the_landmark_noise():
    """Averaging each landmark over a centred window of 5 frames: exact on a hand that translates uniformly (the
    mean of a straight path is its centre), the pose error under 1 cm noise well below the frame-by-frame mapping's,
    and no spurious closes where the noisy aperture dips through the hysteresis band frame by frame."""
    sweep = np.stack([make_pose(np.array([0.4 + 0.005 * t, 0.1, 0.2]), Rotation.from_euler("x", 180, degrees=True))
                      for t in range(30)])
    mapped = map_hand_to_gripper(landmarks_from_gripper(sweep, 0.07), window_frames=5).T_world_ee
    translation, angle = pose_distance(mapped[2:-2], sweep[2:-2])
    assert translation.max() < 1e-9 and np.degrees(angle).max() < 1e-6
    assert pose_distance(mapped[:1], sweep[:1])[0][0] > 1e-3  # fewer frames at the ends: the mean leans inwards

    T_world_ee = smooth_poses(120)
    config = HandMappingConfig(close_below_m=0.055, open_above_m=0.065, gripper_hold_frames=1)
    noisy = landmarks_from_gripper(T_world_ee, 0.075, np.random.default_rng(4), noise_m=0.01)
    errors, changes = {}, {}
    for window in (1, 5):
        trajectory = map_hand_to_gripper(noisy, config, window_frames=window)
        translation, angle = pose_distance(trajectory.T_world_ee, T_world_ee)
        errors[window] = np.median(translation), np.degrees(np.median(angle))
        changes[window] = np.count_nonzero(np.diff(trajectory.gripper_open))
    assert errors[5][0] < 0.6 * errors[1][0] and errors[5][1] < 0.6 * errors[1][1]
    assert changes[1] > 0 and changes[5] == 0


def test_a_window_keeps_missing_landmarks_missing_and_refuses_an_even_width():
    landmarks = landmarks_from_gripper(smooth_poses(20), 0.06)
    landmarks[7] = np.nan
    landmarks[12, 4] = np.nan  # the thumb tip: frame 12 stays missing, its neighbours average without it
    valid = np.ones(20, dtype=bool)
    valid[15] = False
    trajectory = map_hand_to_gripper(landmarks, HandMappingConfig(max_gap_frames=2), valid, window_frames=3)
    np.testing.assert_array_equal(np.flatnonzero(~trajectory.valid), [7, 12, 15])
    assert np.isfinite(trajectory.T_world_ee).all()
    for width in (0, 2):
        with pytest.raises(ValueError, match="window_frames must be an odd number"):
            map_hand_to_gripper(landmarks, window_frames=width)


def test_the_mapping_is_se3_equivariant():
    config = HandMappingConfig(ee_offset_m=(0.01, -0.02, 0.03), position_smoothing=0.3, rotation_smoothing=0.3)
    landmarks = landmarks_from_gripper(smooth_poses(12), 0.06, np.random.default_rng(2), noise_m=0.004)
    T_new_world = make_pose(np.array([0.3, -1.0, 0.5]), Rotation.from_rotvec([0.4, -1.2, 2.0]))
    moved = transform_points(T_new_world, landmarks.reshape(-1, 3)).reshape(landmarks.shape)
    expected = T_new_world @ map_hand_to_gripper(landmarks, config).T_world_ee
    np.testing.assert_allclose(map_hand_to_gripper(moved, config).T_world_ee, expected, atol=1e-9)


def test_gripper_hysteresis_does_not_chatter_near_a_threshold():
    config = HandMappingConfig(close_below_m=0.035, open_above_m=0.05, gripper_hold_frames=1)
    hovering = 0.035 + 0.004 * np.sin(np.arange(30))  # across close_below_m, never above open_above_m
    apertures = np.concatenate([[0.08], hovering, [0.06, 0.045, 0.02, 0.045, 0.06]])
    gripper = map_hand_to_gripper(landmarks_from_gripper(smooth_poses(len(apertures)), apertures), config).gripper_open
    assert gripper[0] == 1
    assert np.count_nonzero(np.diff(gripper[:31])) == 1  # closed once on the first dip, then stays closed
    # opens above 5 cm, closes below 3.5 cm, each change dated to the frame after the aperture last read the old state
    assert np.all(gripper[1:31] == 0)  # closed from the first frame the aperture left the open side
    np.testing.assert_array_equal(gripper[31:], [1, 0, 0, 1, 1])


def test_debounce_ignores_blips_and_dates_a_recorded_change_to_its_first_frame():
    config = HandMappingConfig(close_below_m=0.035, open_above_m=0.05, gripper_hold_frames=3)
    o, c = 0.08, 0.02  # open, closed
    #           0  1  2  3  4  5  6  7  8  9  10 11 12 13
    apertures = [o, o, c, c, o, c, c, c, c, o, c, o, c, o]
    landmarks = landmarks_from_gripper(smooth_poses(len(apertures)), np.array(apertures))
    gripper = map_hand_to_gripper(landmarks, config).gripper_open
    # two closed frames (2-3) and the open blips (9, 11, 13) change nothing; the run of closes from frame 5 does, from 5
    np.testing.assert_array_equal(gripper, [1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    landmarks[6] = np.nan  # a missing frame neither breaks the run nor counts in it
    np.testing.assert_array_equal(map_hand_to_gripper(landmarks, config).gripper_open[4:9], [1, 0, 0, 0, 0])
    undebounced = map_hand_to_gripper(landmarks, HandMappingConfig(close_below_m=0.035, open_above_m=0.05,
                                                                   gripper_hold_frames=1))
    assert np.count_nonzero(np.diff(undebounced.gripper_open)) > 1


def test_debounce_live_changes_late_by_the_hold_less_one():
    T_world_ee = smooth_poses(1)
    step = HandToGripperStateStep(HandMappingConfig(close_below_m=0.035, open_above_m=0.05, gripper_hold_frames=3))
    states = [step.observation({HAND_LANDMARKS_KEY: torch.from_numpy(
        landmarks_from_gripper(T_world_ee, aperture).astype(np.float32))})[STATE_KEY][0, 7].item()
        for aperture in (0.08, 0.02, 0.02, 0.02, 0.02, 0.08, 0.02)]
    assert states == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0]


def test_an_aperture_median_ignores_one_noisy_frame_and_keeps_a_steady_close_in_place():
    apertures = np.where(np.arange(20) < 10, 0.08, 0.02)
    apertures[[3, 15]] = 0.02, 0.08  # one frame each read the other state
    config = HandMappingConfig(close_below_m=0.035, open_above_m=0.055, gripper_hold_frames=1)
    landmarks = landmarks_from_gripper(smooth_poses(20), apertures)
    landmarks[12] = np.nan
    raw = map_hand_to_gripper(landmarks, config)
    median = map_hand_to_gripper(landmarks, config, aperture_window_frames=5)
    assert np.count_nonzero(np.diff(raw.gripper_open)) == 5  # the close, and each spike there and back
    np.testing.assert_array_equal(median.gripper_open, (np.arange(20) < 10).astype(float))
    np.testing.assert_array_equal(median.T_world_ee, raw.T_world_ee)  # the poses are not smoothed
    with pytest.raises(ValueError, match="odd"):
        map_hand_to_gripper(landmarks, config, aperture_window_frames=4)


def test_a_dwell_averages_the_poses_a_grasp_and_a_release_happen_at():
    """A hand sweeping, then holding still over 6 frames at a grasp and 6 at a release: with ``dwell_frames`` 4 the 4
    frames from each change share the mean of their poses under 5 mm landmark noise, at under 0.7 of the
    frame-by-frame error over 100 such demonstrations, every other frame as mapped frame by frame; 0 is refused."""
    sweep = smooth_poses(30)
    T_world_ee = np.concatenate([sweep[:10], np.repeat(sweep[10:11], 6, axis=0), sweep[10:20],
                                 np.repeat(sweep[20:21], 6, axis=0), sweep[20:]])
    apertures = np.full(len(T_world_ee), 0.1)
    apertures[10:26] = 0.01  # closed from the first still frame of the grasp to the first of the release
    config = HandMappingConfig(close_below_m=0.035, open_above_m=0.075, gripper_hold_frames=1)
    errors = {1: [], 4: []}
    rng = np.random.default_rng(5)
    for _ in range(100):
        landmarks = landmarks_from_gripper(T_world_ee, apertures, rng, noise_m=0.005)
        raw, held = (map_hand_to_gripper(landmarks, config, aperture_window_frames=5, dwell_frames=dwell)
                     for dwell in (1, 4))
        np.testing.assert_array_equal(held.gripper_open, raw.gripper_open)
        changes = np.flatnonzero(np.diff(raw.gripper_open)) + 1
        assert len(changes) == 2 and np.all(np.abs(changes - (10, 26)) <= 1)
        dwelling = np.concatenate([np.arange(change, change + 4) for change in changes])
        np.testing.assert_array_equal(held.T_world_ee[np.setdiff1d(np.arange(len(T_world_ee)), dwelling)],
                                      raw.T_world_ee[np.setdiff1d(np.arange(len(T_world_ee)), dwelling)])
        for change in changes:
            np.testing.assert_allclose(held.T_world_ee[change:change + 4], held.T_world_ee[change][None].repeat(4, 0))
        for dwell, trajectory in ((1, raw), (4, held)):
            errors[dwell].append(pose_distance(trajectory.T_world_ee[changes], T_world_ee[changes])[0])
    assert np.median(errors[4]) < 0.7 * np.median(errors[1])
    with pytest.raises(ValueError, match="dwell_frames"):
        map_hand_to_gripper(landmarks, config, dwell_frames=0)


def test_nan_frames_are_marked_and_bridged_without_a_jump():
    T_world_ee = smooth_poses(20)
    landmarks = landmarks_from_gripper(T_world_ee, 0.06)
    landmarks[[0, 7, 8, 19]] = np.nan
    landmarks[12, 4] = np.nan  # one needed landmark (the thumb tip)
    valid = np.ones(20, dtype=bool)
    valid[15] = False
    trajectory = map_hand_to_gripper(landmarks, HandMappingConfig(max_gap_frames=2), valid=valid)
    np.testing.assert_array_equal(np.flatnonzero(~trajectory.valid), [0, 7, 8, 12, 15, 19])
    assert np.isfinite(trajectory.T_world_ee).all()
    translation, angle = pose_distance(trajectory.T_world_ee, T_world_ee)
    assert translation[1:19].max() < 1e-9 and np.degrees(angle[1:19]).max() < 1e-6  # SLERP on a uniform turn
    np.testing.assert_allclose(trajectory.T_world_ee[0], T_world_ee[1], atol=1e-9)  # the ends hold the nearest pose
    np.testing.assert_allclose(trajectory.T_world_ee[19], T_world_ee[18], atol=1e-9)


def test_long_gap_degenerate_hand_and_bad_shape_raise():
    landmarks = landmarks_from_gripper(smooth_poses(10), 0.06)
    landmarks[3:7] = np.nan
    with pytest.raises(HandGapError, match="frames 3..6"):
        map_hand_to_gripper(landmarks, HandMappingConfig(max_gap_frames=3))
    degenerate = landmarks_from_gripper(smooth_poses(3), 0.06)
    degenerate[1, 8] = degenerate[1, 4]  # index tip on the thumb tip: the finger axis is undefined
    assert not map_hand_to_gripper(degenerate).valid[1]
    with pytest.raises(ValueError, match=r"\(T, 21, 3\).*\(5, 20, 3\)"):
        map_hand_to_gripper(np.zeros((5, 20, 3)))
    with pytest.raises(HandGapError, match="no frame"):
        map_hand_to_gripper(np.full((4, 21, 3), np.nan))


def bone_samples(landmarks: np.ndarray, count: int = 200) -> np.ndarray:
    """``(21 * count, 3)`` points evenly along every bone of ``landmarks (21, 3)``."""
    ends = landmarks[np.array(HAND_BONES)]
    return (ends[:, None, 0] + np.linspace(0, 1, count)[:, None] * (ends[:, None, 1] - ends[:, None, 0])).reshape(-1, 3)


def distance_to(points: np.ndarray, samples: np.ndarray) -> np.ndarray:
    return np.linalg.norm(points[:, None] - samples[None], axis=-1).min(axis=1)


def test_mask_removes_the_hand_volume_and_keeps_an_object_nearby():
    rng = np.random.default_rng(0)
    T_world_ee = random_poses(1, seed=5, extent_m=0.5)[0]
    landmarks = landmarks_from_gripper(T_world_ee, 0.05)
    radius = 0.012
    ends = landmarks[np.array(HAND_BONES)]  # (bones, 2, 3)
    along = rng.uniform(0, 1, (len(ends), 200, 1))
    offsets = rng.normal(size=(len(ends), 200, 3))
    offsets *= rng.uniform(0, 0.98 * radius, (len(ends), 200, 1)) / np.linalg.norm(offsets, axis=-1, keepdims=True)
    in_hand = (ends[:, None, 0] + along * (ends[:, None, 1] - ends[:, None, 0]) + offsets).reshape(-1, 3)
    direction = rng.normal(size=(500, 3))
    centre = transform_points(T_world_ee, np.array([[0.0, 0.0, 0.1]]))  # 10 cm ahead of the fingertips
    obj = centre + 0.04 * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    obj = obj[distance_to(obj, bone_samples(landmarks)) > 0.05 + radius]  # 5 cm from the hand's surface
    assert len(obj) > 300
    keep = mask_hand_points(np.concatenate([in_hand, obj]), landmarks, radius)
    assert not keep[: len(in_hand)].any() and keep[len(in_hand):].all()
    batched = mask_hand_points(np.stack([obj, obj]), np.stack([landmarks, landmarks + 1.0]), radius)
    assert batched.shape == (2, len(obj)) and batched.all()


def test_the_palm_between_the_bones_is_removed():
    landmarks = landmarks_from_gripper(random_poses(1, seed=6, extent_m=0.5)[0], 0.05)
    radius = 0.008
    corners = landmarks[[0, 1, 5]]  # the palm triangle wrist, thumb CMC, index MCP
    normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    normal /= np.linalg.norm(normal)
    points = corners.mean(axis=0) + np.array([[0.005], [0.012]]) * normal  # 5 mm / 12 mm off the palm's plane
    assert distance_to(points, bone_samples(landmarks)).min() > radius  # no bone's capsule holds them
    np.testing.assert_array_equal(mask_hand_points(points, landmarks, radius), [False, True])


def test_mask_with_missing_landmarks():
    landmarks = landmarks_from_gripper(np.eye(4), 0.05)
    points = landmarks.copy()
    assert mask_hand_points(points, np.full((21, 3), np.nan), 0.01).all()  # no hand in view
    landmarks[20] = np.nan
    with pytest.raises(ValueError, match=r"\[20\] are NaN"):
        mask_hand_points(points, landmarks, 0.01)


def test_mask_steps_clear_the_cloud_mask():
    landmarks = landmarks_from_gripper(np.eye(4), 0.05)
    far = np.array([[1.0, 1.0, 1.0]])
    cloud = np.concatenate([landmarks, far])[None].astype(np.float32)
    observation = {POINTCLOUD_KEY: cloud, CLOUD_MASK_KEY: np.ones((1, 22), dtype=bool)}
    mask = MaskHandPointsStep(radius_m=0.01).observation({**observation, HAND_LANDMARKS_KEY: landmarks[None]})
    mask = mask[CLOUD_MASK_KEY]
    np.testing.assert_array_equal(mask[0], [False] * 21 + [True])
    hand_pixels = np.zeros((1, 2, 6, 8), dtype=bool)
    hand_pixels[0, 1, 2, 3] = True
    observation = {POINTCLOUD_KEY: np.zeros((1, 96, 3), np.float32), CLOUD_MASK_KEY: np.ones((1, 96), dtype=bool),
                   HAND_MASK_KEY: hand_pixels}
    out = ClearHandPixelsStep(dilate_px=1).observation(observation)
    cleared = ~out[CLOUD_MASK_KEY].reshape(2, 6, 8)
    assert HAND_MASK_KEY not in out and not cleared[0].any()
    assert cleared[1].sum() == 9 and cleared[1, 1:4, 2:5].all()
    with pytest.raises(ValueError, match="after DepthToPointCloudStep"):
        ClearHandPixelsStep().observation({**observation, CLOUD_MASK_KEY: np.ones((1, 50), dtype=bool)})


def test_processor_step_keeps_state_across_calls_and_resets():
    T_world_ee = smooth_poses(2)
    step = HandToGripperStateStep(HandMappingConfig(max_gap_frames=1, gripper_hold_frames=1))

    def call(aperture: float, pose: int = 0) -> dict:
        landmarks = torch.from_numpy(landmarks_from_gripper(T_world_ee[[pose, pose]], aperture).astype(np.float32))
        return step.observation({HAND_LANDMARKS_KEY: landmarks})

    out = call(0.02)
    state = out[STATE_KEY]
    assert state.shape == (2, 8) and state.dtype == torch.float32 and HAND_LANDMARKS_KEY in out
    np.testing.assert_allclose(poses_from_vectors(state[0].numpy())[0], T_world_ee[0], atol=1e-5)
    assert state[:, 7].tolist() == [0.0, 0.0] and out[HAND_VALID_KEY].tolist() == [True, True]
    assert call(0.04)[STATE_KEY][:, 7].tolist() == [0.0, 0.0]  # between the thresholds: stays closed
    step.reset()
    assert call(0.04)[STATE_KEY][:, 7].tolist() == [1.0, 1.0]  # a fresh stream starts open
    missing = torch.full((2, 21, 3), float("nan"))
    held = step.observation({HAND_LANDMARKS_KEY: missing})
    torch.testing.assert_close(held[STATE_KEY], call(0.04)[STATE_KEY])
    assert held[HAND_VALID_KEY].tolist() == [False, False]
    step.observation({HAND_LANDMARKS_KEY: missing})
    with pytest.raises(HandGapError, match="max_gap_frames"):
        step.observation({HAND_LANDMARKS_KEY: missing})
    with pytest.raises(ValueError, match="reset"):
        step.observation({HAND_LANDMARKS_KEY: missing[:1]})
    step.reset()
    with pytest.raises(HandGapError, match="none found yet"):
        step.observation({HAND_LANDMARKS_KEY: missing})
    assert step.transform_features({})[PipelineFeatureType.OBSERVATION][STATE_KEY].shape == (8,)


def test_hand_steps_save_and_load_with_a_pipeline(tmp_path):
    config = HandMappingConfig(close_below_m=0.03, palm_landmarks=(0, 9, 13), ee_offset_m=(0.0, 0.0, -0.01))
    steps = [ClearHandPixelsStep(dilate_px=3), MaskHandPointsStep(radius_m=0.02), HandToGripperStateStep(config)]
    PolicyProcessorPipeline(steps=steps, name="hand").save_pretrained(tmp_path)
    loaded = PolicyProcessorPipeline.from_pretrained(tmp_path, config_filename="hand.json").steps
    assert [step.get_config() for step in loaded] == [step.get_config() for step in steps]
    assert loaded[2].config == config


def test_lifting_image_landmarks_on_a_plane():
    intrinsics = np.array([[300.0, 0.0, 63.5], [0.0, 300.0, 47.5], [0.0, 0.0, 1.0]])
    T_world_camera = make_pose(np.array([0.5, -0.3, 0.8]), Rotation.from_euler("xyz", [200, 15, 10], degrees=True))
    height, width = 96, 128
    rows, cols = np.mgrid[0:height, 0:width]

    def plane_depth(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Camera-frame z of the table plane world z = 0 along the rays of pixels ``(u, v)``."""
        rays = np.stack([(u - 63.5) / 300.0, (v - 47.5) / 300.0, np.ones_like(u, dtype=float)], axis=-1)
        return -T_world_camera[2, 3] / (rays @ T_world_camera[2, :3])

    depth = plane_depth(cols, rows)
    assert (depth > 0.3).all()
    rng = np.random.default_rng(0)
    pixels = np.stack([rng.uniform(10, width - 10, 21), rng.uniform(10, height - 10, 21)], axis=-1)
    z = plane_depth(pixels[:, 0], pixels[:, 1])
    camera_points = np.stack([(pixels[:, 0] - 63.5) / 300.0 * z, (pixels[:, 1] - 47.5) / 300.0 * z, z], axis=-1)
    truth = transform_points(T_world_camera, camera_points)
    np.testing.assert_allclose(truth[:, 2], 0.0, atol=1e-9)
    depth = np.stack([depth, depth])
    column, row = np.round(pixels[3]).astype(int)
    depth[0, row, column] = np.nan  # one missing pixel: the window's median still finds the plane
    depth[1, row - 2:row + 3, column - 2:column + 3] = 0.0  # no return around the landmark
    pixels = np.stack([pixels, pixels])
    pixels[1, 5] = (-3.0, 10.0)  # outside the image
    pixels[1, 6] = np.nan  # not detected
    lifted = lift_image_landmarks(pixels, depth, intrinsics, T_world_camera)
    assert lifted.shape == (2, 21, 3)
    np.testing.assert_allclose(lifted[0], truth, atol=2e-3)
    assert np.isnan(lifted[1, [3, 5, 6]]).all() and np.isfinite(np.delete(lifted[1], [3, 5, 6], axis=0)).all()
    with pytest.raises(ValueError, match=r"\(T, 21, 2\)"):
        lift_image_landmarks(pixels[..., :1], depth, intrinsics, T_world_camera)
