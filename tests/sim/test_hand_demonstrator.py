"""The simulated human demonstrator (``sim.hand_model``, ``sim.hand_demonstrator``): its landmarks read back as the
scripted gripper, it moves objects, its noisy recordings convert, and the hand never reaches an object cloud."""

from __future__ import annotations

import numpy as np
import pybullet
import pytest

from lerobot_instant_policy.cli.record_demos import main as record_main
from lerobot_instant_policy.contract import poses_from_vectors
from lerobot_instant_policy.data.demonstrations import load_demonstrations
from lerobot_instant_policy.geometry.se3 import pose_distance
from lerobot_instant_policy.perception.hand import map_hand_to_gripper
from lerobot_instant_policy.perception.hand_convert import HandConvertSettings
from lerobot_instant_policy.perception.hand_mask import mask_hand_points
from lerobot_instant_policy.perception.hand_recording import find_hand_recordings, load_hand_recording
from lerobot_instant_policy.sim.demonstrator import top_down_pose
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from lerobot_instant_policy.sim.hand_demonstrator import (
    SIM_HAND_MAPPING,
    HandDemonstratorConfig,
    perform_hand_demonstration,
    record_hand_demonstrations,
)
from lerobot_instant_policy.sim.hand_model import FINGERS, MAX_APERTURE, MIN_APERTURE, SimulatedHand

SMALL_CAMERAS = dict(obs_type="rgbd", success="instant", depth_resolution=(160, 120), num_points=256)
EXACT = HandDemonstratorConfig(landmark_noise_m=0.0, drop_probability=0.0, approach_jitter_m=0.0)


def test_hand_model_reads_back_as_the_gripper_pose_and_aperture():
    client = pybullet.connect(pybullet.DIRECT)
    try:
        hand = SimulatedHand(client)
        rng = np.random.default_rng(0)
        poses = np.stack([top_down_pose(rng.uniform((0.4, -0.2, 0.02), (0.6, 0.2, 0.3)), rng.uniform(-np.pi, np.pi))
                          for _ in range(12)])
        apertures = np.linspace(MIN_APERTURE, MAX_APERTURE, 12)
        landmarks = []
        for pose, aperture in zip(poses, apertures, strict=True):
            hand.set_pose(pose, aperture)
            landmarks.append(hand.landmarks())
        landmarks = np.stack(landmarks)
    finally:
        pybullet.disconnect(client)
    assert np.linalg.norm(landmarks[:, 4] - landmarks[:, 8], axis=1) == pytest.approx(apertures, abs=1e-6)
    translation, rotation = pose_distance(map_hand_to_gripper(landmarks, SIM_HAND_MAPPING).T_world_ee, poses)
    assert translation.max() < 1e-5 and np.degrees(rotation).max() < 1e-3


@pytest.fixture(scope="module")
def exact_demonstration():
    """A pick_and_lift demonstration by the hand without noise, drops or jitter, the block's height after it and the
    scripted plan."""
    env = BulletTabletopEnv("pick_and_lift", BulletTabletopConfig(**SMALL_CAMERAS))
    try:
        demonstration = perform_hand_demonstration(env, 3, EXACT)
        block_height = env.scene.pose(env.task_impl.block)[2, 3]
        env.reset(seed=3)
        plan = env.scripted_actions()
    finally:
        env.close()
    return demonstration, block_height, plan


def test_landmarks_map_back_to_the_scripted_gripper_within_5_mm_and_3_degrees(exact_demonstration):
    demonstration, _, plan = exact_demonstration
    trajectory = map_hand_to_gripper(demonstration.recording.landmarks_world, SIM_HAND_MAPPING)
    frames = demonstration.recording.num_frames
    scripted, scripted_open = poses_from_vectors(plan[: frames - 1])  # the pose reached after each step
    translation, rotation = pose_distance(trajectory.T_world_ee[1:], scripted)
    assert translation.max() < 0.005 and np.degrees(rotation).max() < 3.0
    # the gripper state follows the script but for the frames the fingers take to close or open
    assert np.mean(trajectory.gripper_open[1:] == scripted_open) > 0.85
    assert (trajectory.gripper_open == 0).any() and demonstration.aperture.min() > 0.05  # closed on the 4 cm block


def test_the_hand_lifts_the_block(exact_demonstration):
    demonstration, block_height, _ = exact_demonstration
    assert demonstration.success and block_height > 0.12  # from 0.02 m on the table


def test_the_robot_replaying_the_mapped_hand_lifts_the_block(exact_demonstration):
    """The mapped demonstration, its actions the next frames' states (the last held), replayed open loop by the robot
    on the same scene, meets pick_and_lift's held success: the recording goes on past the goal, so its last state
    is past it too."""
    demonstration, _, _ = exact_demonstration
    states = map_hand_to_gripper(demonstration.recording.landmarks_world, SIM_HAND_MAPPING).state_vectors()
    env = BulletTabletopEnv("pick_and_lift", BulletTabletopConfig(**{**SMALL_CAMERAS, "obs_type": "pointcloud",
                                                                     "success": "held"}))
    try:
        env.reset(seed=demonstration.seed)
        successes = [env.step(action)[4]["is_success"] for action in [*states[1:], *[states[-1]] * 10]]
    finally:
        env.close()
    assert any(successes)


def test_a_placement_records_its_release_and_maps_to_the_scripts_grasp_and_release():
    """Under the default landmark noise and drops, a put_in_tray demonstration goes on past the goal until the pinch
    has let go, and the conversion's mapping finds the script's one grasp and one release within the frames the
    fingers take to move."""
    env = BulletTabletopEnv("put_in_tray", BulletTabletopConfig(**SMALL_CAMERAS))
    try:
        demonstration = perform_hand_demonstration(env, 0)
    finally:
        env.close()
    assert demonstration.success and demonstration.aperture[-1] > SIM_HAND_MAPPING.open_above_m
    mapped = map_hand_to_gripper(demonstration.recording.landmarks_world, SIM_HAND_MAPPING,
                                 aperture_window_frames=HandConvertSettings.aperture_window_frames).gripper_open
    scripted_changes = np.flatnonzero(np.diff(demonstration.pinch_open)) + 1
    mapped_changes = np.flatnonzero(np.diff(mapped)) + 1
    assert len(scripted_changes) == len(mapped_changes) == 2 and mapped[-1] == 1.0
    assert np.all((mapped_changes >= scripted_changes) & (mapped_changes <= scripted_changes + 3))


@pytest.mark.slow
def test_no_hand_point_reaches_an_object_cloud(tmp_path):
    """Without the segmentation's masks (a detector with landmarks only, the table plane for the objects) and with
    them: every converted cloud point lies farther than a finger's radius from the hand's true skeleton."""
    radius = max(finger.radius for finger in FINGERS) + 0.002
    for record_hand_mask in (False, True):
        out = tmp_path / f"mask-{record_hand_mask}"
        config = HandDemonstratorConfig(landmark_noise_m=0.0, drop_probability=0.0, record_hand_mask=record_hand_mask,
                                        record_object_mask=record_hand_mask)
        record_hand_demonstrations("pick_and_lift", 1, out, "local/pick_and_lift", 5, config,
                                   env_config=BulletTabletopConfig(**SMALL_CAMERAS))
        (demonstration,) = load_demonstrations("local/pick_and_lift", out, "pick_and_lift", 1)
        (folder,) = find_hand_recordings(out.with_name(out.name + "-recordings"))
        landmarks = load_hand_recording(folder).landmarks_world
        for points, hand in zip(demonstration.points_world, landmarks, strict=True):
            assert mask_hand_points(points, hand, radius).all()


@pytest.mark.slow
def test_the_objects_mask_keeps_slide_blocks_flat_target(tmp_path):
    """slide_block's target is a square 1 mm high: with the segmentation's object mask every converted cloud holds
    it, as the robot's own demonstrations do; from depth alone the table plane takes it with the table."""
    for record_object_mask in (False, True):
        out = tmp_path / f"objects-{record_object_mask}"
        config = HandDemonstratorConfig(record_object_mask=record_object_mask)
        record_hand_demonstrations("slide_block", 1, out, "local/slide_block", 0, config,
                                   env_config=BulletTabletopConfig(**SMALL_CAMERAS))
        (demonstration,) = load_demonstrations("local/slide_block", out, "slide_block", 1)
        on_table = (demonstration.points_world[..., 2] < 0.005).sum(axis=1)
        assert (on_table > 0).all() if record_object_mask else (on_table == 0).all()


@pytest.mark.slow
def test_noisy_demonstrations_convert_and_replay_as_context(tmp_path, capsys):
    out = tmp_path / "hand"
    assert record_main(["--demonstrator", "hand", "--task", "push_button", "--episodes", "2", "--out", str(out),
                        "--repo-id", "local/push_button", "--seed", "0", "--hand-drop-probability", "0.3"]) == 0
    assert "wrote 2 hand demonstrations" in capsys.readouterr().out
    demonstrations = load_demonstrations("local/push_button", out, "push_button", 2)
    recordings = [load_hand_recording(folder) for folder in find_hand_recordings(tmp_path / "hand-recordings")]
    assert len(recordings) == 2 and all(np.isnan(r.landmarks_world).all(axis=(1, 2)).any() for r in recordings)
    for demonstration, recording in zip(demonstrations, recordings, strict=True):
        assert len(demonstration.state) == recording.num_frames
        assert np.all(np.isfinite(demonstration.state)) and set(np.unique(demonstration.state[:, 7])) <= {0.0, 1.0}
