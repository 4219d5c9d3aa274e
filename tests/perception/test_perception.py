"""Depth → segmented world-frame clouds (``lerobot_instant_policy.perception``): geometry, segmentation, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.geometry.se3 import make_pose
from lerobot_instant_policy.perception.calibration import (
    CalibrationError,
    calibration_from_dataset_features,
    load_calibration,
    save_calibration,
)
from lerobot_instant_policy.perception.depth import DepthRange, DepthUnitError, backproject
from lerobot_instant_policy.perception.pipeline import PerceptionConfig, make_perception_pipeline
from lerobot_instant_policy.perception.robot_model import RobotModel
from lerobot_instant_policy.perception.segmentation import EmptyPointCloudError, fit_horizontal_plane
from lerobot_instant_policy.perception.steps import (
    CLOUD_MASK_KEY,
    DEPTH_KEY,
    EXTRINSICS_KEY,
    INTRINSICS_KEY,
    OBJECT_MASK_KEY,
    DepthToPointCloudStep,
    RemoveGripperStep,
    RemoveTablePlaneStep,
    ResamplePointCloudStep,
)
from lerobot_instant_policy.sim.configuration_bullet_tabletop import BulletTabletopEnvConfig, rgbd_perception_config
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from lerobot_instant_policy.sim.robot import JOINT_NAMES, low_poly_panda_urdf

CLOUD_KEY = "observation.pointcloud"
INTRINSICS = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])


def looking_down(height: float) -> np.ndarray:
    """``T_world_camera`` of a camera ``height`` m above the origin looking straight down (OpenCV frame)."""
    return make_pose(np.array([0.5, 0.0, height]), Rotation.from_euler("x", 180, degrees=True))


def camera_batch(depth: np.ndarray, pose: np.ndarray, intrinsics: np.ndarray = INTRINSICS) -> dict:
    """A one-camera, one-row batch of ``depth (H, W)`` metres."""
    return {
        DEPTH_KEY: torch.from_numpy(depth[None, None].astype(np.float32)),
        INTRINSICS_KEY: torch.from_numpy(intrinsics[None, None].copy()),
        EXTRINSICS_KEY: torch.from_numpy(pose[None, None].copy()),
    }


def table_with_box(height: float = 0.8) -> np.ndarray:
    """Depth ``(48, 64)`` of a table plane at z = 0 seen from ``height`` m, with a 6 cm tall box in the middle."""
    depth = np.full((48, 64), height)
    depth[18:30, 26:38] = height - 0.06
    return depth


@pytest.fixture(scope="module")
def rgbd_and_segmented():
    """The same pick_and_lift scene after 20 scripted steps in both observation modes."""
    clouds = {}
    for obs_type in ("pointcloud", "rgbd"):
        env = BulletTabletopEnv("pick_and_lift", BulletTabletopConfig(obs_type=obs_type))
        observation, _ = env.reset(seed=4)
        for action in env.scripted_actions()[:20]:
            observation = env.step(action)[0]
        clouds[obs_type] = observation
        env.close()
    return clouds


def run_pipeline(observation: dict, config: PerceptionConfig) -> np.ndarray:
    from lerobot.envs.utils import preprocess_observation

    batch = preprocess_observation({key: value[None] for key, value in observation.items()})
    return make_perception_pipeline(config)(batch)[CLOUD_KEY][0].numpy()


def test_rgbd_cloud_matches_the_simulators_segmented_cloud(rgbd_and_segmented):
    processed = run_pipeline(rgbd_and_segmented["rgbd"], rgbd_perception_config())
    segmented = rgbd_and_segmented["pointcloud"]["pointcloud"]
    assert processed.shape == (2048, 3) and processed.dtype == np.float32
    to_segmented, _ = cKDTree(segmented).query(processed)
    to_processed, _ = cKDTree(processed).query(segmented)
    assert np.percentile(to_segmented, 99) < 0.01  # no table, robot or background points
    assert np.max(to_segmented) < 0.02
    assert np.median(to_processed) < 0.006  # and the objects are covered


def test_env_rgbd_observation_and_processor(rgbd_and_segmented):
    observation = rgbd_and_segmented["rgbd"]
    assert observation["depth"].shape == (3, 180, 240) and observation["depth"].dtype == np.float32
    assert observation["intrinsics"].shape == (3, 3, 3) and observation["T_world_camera"].shape == (3, 4, 4)
    assert observation["joint_positions"].shape == (9,) and "pointcloud" not in observation
    assert (observation["depth"] == 0).any()  # no return beyond the table
    config = BulletTabletopEnvConfig(obs_type="rgbd")
    preprocessor, _ = config.get_env_processors()
    assert "observation.pointcloud" in config.features_map.values()
    assert [type(step).__name__ for step in preprocessor.steps][-1] == "ResamplePointCloudStep"
    assert BulletTabletopEnvConfig().get_env_processors()[0].steps == []


def test_env_calibration_error_and_noise_have_the_asked_size():
    config = BulletTabletopConfig(
        obs_type="rgbd", depth_noise_std=0.003, calibration_error_translation=0.02, calibration_error_rotation_deg=2.0
    )
    env = BulletTabletopEnv("push_button", config)
    clean = BulletTabletopEnv("push_button", BulletTabletopConfig(obs_type="rgbd"))
    noisy_observation, _ = env.reset(seed=1)
    clean_observation, _ = clean.reset(seed=1)
    for reported, true in zip(noisy_observation["T_world_camera"], clean_observation["T_world_camera"], strict=True):
        assert np.linalg.norm(reported[:3, 3] - true[:3, 3]) == pytest.approx(0.02, abs=1e-5)
        angle = Rotation.from_matrix(reported[:3, :3] @ true[:3, :3].T).magnitude()
        assert np.degrees(angle) == pytest.approx(2.0, abs=1e-3)
    returns = clean_observation["depth"] > 0
    difference = noisy_observation["depth"][returns] - clean_observation["depth"][returns]
    assert np.std(difference) == pytest.approx(0.003, rel=0.1)
    env.close()
    clean.close()


def test_intrinsics_follow_the_renderer(rgbd_and_segmented):
    """A pixel's back-projection lies on the ray the renderer drew it along: the object points of the rgbd
    cloud coincide with the segmented ones, which pybullet's own inverse projection gives."""
    env = BulletTabletopEnv("push_button", BulletTabletopConfig(obs_type="rgbd"))
    env.reset(seed=0)
    intrinsics, pose = env.camera_intrinsics()[0], env.camera_poses()[0]
    assert intrinsics[0, 2] == pytest.approx(119.5) and intrinsics[1, 2] == pytest.approx(89.5)
    assert pose[:3, 3] == pytest.approx(env.config.cameras[0].eye)
    optical_axis = pose[:3, 2]
    target = np.asarray(env.config.cameras[0].target) - np.asarray(env.config.cameras[0].eye)
    assert optical_axis == pytest.approx(target / np.linalg.norm(target), abs=1e-6)
    env.close()


def test_camera_pose_error_shifts_the_cloud_as_expected():
    depth, pose = table_with_box(), looking_down(0.8)
    points, valid = backproject(depth, INTRINSICS, pose, DepthRange())
    offset = np.array([0.01, -0.02, 0.005])
    shifted_pose = pose.copy()
    shifted_pose[:3, 3] += offset
    shifted, _ = backproject(depth, INTRINSICS, shifted_pose, DepthRange())
    assert valid.all()
    assert shifted - points == pytest.approx(np.broadcast_to(offset, points.shape), abs=1e-6)
    turn = make_pose(np.zeros(3), Rotation.from_euler("z", 5, degrees=True))
    turned, _ = backproject(depth, INTRINSICS, turn @ pose, DepthRange())
    assert turned == pytest.approx(points @ turn[:3, :3].T, abs=1e-5)
    assert points[:, 2].min() == pytest.approx(0.0, abs=1e-6) and points[:, 2].max() == pytest.approx(0.06, abs=1e-6)


def test_table_plane_is_removed_and_the_box_kept():
    batch = camera_batch(table_with_box(), looking_down(0.8))
    cloud = DepthToPointCloudStep().observation(batch)
    kept = RemoveTablePlaneStep().observation(cloud)
    points = cloud[CLOUD_KEY][0][kept[CLOUD_MASK_KEY][0]]
    assert len(points) == 12 * 12 and np.allclose(points[:, 2], 0.06, atol=1e-5)
    tilted = np.c_[np.random.default_rng(0).uniform(-1, 1, (500, 2)), np.zeros(500)]
    tilted = tilted @ Rotation.from_euler("x", 40, degrees=True).as_matrix().T
    assert fit_horizontal_plane(tilted, np.random.default_rng(0), 0.005) is None  # a wall is not a table


def test_user_mask_selects_the_pixels():
    batch = camera_batch(table_with_box(), looking_down(0.8))
    mask = np.zeros((48, 64), dtype=bool)
    mask[20:22, 30:33] = True
    batch[OBJECT_MASK_KEY] = torch.from_numpy(mask[None, None])
    cloud = DepthToPointCloudStep().observation(batch)
    assert cloud[CLOUD_MASK_KEY].sum() == 6 and OBJECT_MASK_KEY not in cloud and DEPTH_KEY not in cloud


def test_resample_gives_fixed_size_or_a_clear_error():
    cloud = DepthToPointCloudStep().observation(camera_batch(table_with_box(), looking_down(0.8)))
    resampled = ResamplePointCloudStep(num_points=100).observation(dict(cloud))
    assert resampled[CLOUD_KEY].shape == (1, 100, 3) and CLOUD_MASK_KEY not in resampled
    cloud[CLOUD_MASK_KEY][:] = False
    with pytest.raises(EmptyPointCloudError, match="0 points of the task objects"):
        ResamplePointCloudStep().observation(cloud)


def test_pipeline_raises_when_the_workspace_holds_nothing():
    config = PerceptionConfig(workspace_low=(2.0, 2.0, 0.0), workspace_high=(3.0, 3.0, 1.0))
    with pytest.raises(EmptyPointCloudError):
        make_perception_pipeline(config)(
            {**camera_batch(table_with_box(), looking_down(0.8)), "observation.state": torch.tensor([[0, 0, 2, 0, 0, 0, 1, 1.0]])}
        )


def test_millimetres_given_as_metres_raise():
    millimetres = table_with_box() * 1000
    with pytest.raises(DepthUnitError, match="millimetres"):
        DepthToPointCloudStep().observation(camera_batch(millimetres, looking_down(0.8)))
    with pytest.raises(DepthUnitError, match="divided by 1000"):
        DepthToPointCloudStep().observation(camera_batch(table_with_box() / 1000, looking_down(0.8)))


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda b: b.pop(INTRINSICS_KEY), "no camera parameters"),
        (lambda b: b.__setitem__(INTRINSICS_KEY, b[INTRINSICS_KEY] * torch.tensor([1, 1, 0.0])), "pinhole"),
        (lambda b: b[INTRINSICS_KEY][..., 0, 2].fill_(400.0), "outside"),
        (lambda b: b[INTRINSICS_KEY][..., 0, 0].fill_(-5.0), "positive"),
        (lambda b: b[EXTRINSICS_KEY][..., :3, :3].mul_(2.0), "not a rotation"),
        (lambda b: b[EXTRINSICS_KEY][..., :3, 0].mul_(-1.0), "not a rotation"),
        (lambda b: b[EXTRINSICS_KEY][..., :3, 3].mul_(1000.0), "millimetres"),
        (lambda b: b.__setitem__(EXTRINSICS_KEY, b[EXTRINSICS_KEY].repeat(1, 2, 1, 1)), "extrinsics for 2"),
        (lambda b: b[EXTRINSICS_KEY][..., 0, 3].fill_(float("nan")), "finite"),
    ],
)
def test_bad_camera_parameters_raise(change, message):
    batch = camera_batch(table_with_box(), looking_down(0.8))
    change(batch)
    with pytest.raises(CalibrationError, match=message):
        DepthToPointCloudStep().observation(batch)


def calibration_entry(**overrides) -> dict:
    entry = {
        "name": "top",
        "depth_key": "observation.images.top_depth",
        "width": 64,
        "height": 48,
        "fx": 100.0,
        "fy": 100.0,
        "cx": 31.5,
        "cy": 23.5,
        "depth_unit": "mm",
        "T_world_camera": looking_down(0.8).tolist(),
    }
    return {**entry, **overrides}


def test_calibration_file_round_trip_and_millimetre_depth(tmp_path):
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps({"cameras": [calibration_entry()]}))
    cameras = load_calibration(path)
    save_calibration(cameras, tmp_path / "again.json")
    assert load_calibration(tmp_path / "again.json") == cameras
    config = PerceptionConfig(num_points=64, calibration_path=str(path), table_distance_threshold=0.005)
    depth_mm = torch.from_numpy((table_with_box() * 1000).astype(np.uint16)[None, None].astype(np.float32))
    cloud = make_perception_pipeline(config)(
        {"observation.images.top_depth": depth_mm, "observation.state": torch.tensor([[0, 0, 2, 0, 0, 0, 1, 1.0]])}
    )[CLOUD_KEY][0].numpy()
    assert cloud.shape == (64, 3) and np.allclose(cloud[:, 2], 0.06, atol=1e-3)
    small = torch.zeros(1, 1, 24, 32)
    with pytest.raises(CalibrationError, match="calibration is for 64x48"):
        make_perception_pipeline(config)({"observation.images.top_depth": small})


@pytest.mark.parametrize(
    "document, message",
    [
        ({"cameras": []}, "no non-empty 'cameras'"),
        ({"cameras": [calibration_entry(fx=None)]}, "lacks \\['fx'\\]"),
        ({"cameras": [calibration_entry(focal=3)]}, "unknown camera fields"),
        ({"cameras": [calibration_entry(depth_unit="cm")]}, "depth_unit"),
        ({"cameras": [calibration_entry(T_world_camera=[[1, 0, 0], [0, 1, 0], [0, 0, 1]])]}, "4x4"),
        ({"cameras": [calibration_entry(depth_key="")]}, "no depth_key"),
    ],
)
def test_bad_calibration_files_raise(tmp_path, document, message):
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(document))
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


def test_calibration_from_dataset_metadata():
    entry = {key: value for key, value in calibration_entry().items() if key not in ("name", "depth_key")}
    features = {
        "observation.images.top_depth": {"dtype": "image", "info": {"is_depth_map": True, "camera_calibration": entry}},
        "observation.images.rgb": {"dtype": "image", "info": {}},
    }
    (camera,) = calibration_from_dataset_features(features)
    assert camera.depth_key == "observation.images.top_depth" and camera.fx == 100.0
    features["observation.images.side_depth"] = {"dtype": "image", "info": {"is_depth_map": True}}
    with pytest.raises(CalibrationError, match="side_depth"):
        calibration_from_dataset_features(features)


def test_gripper_box_removes_the_hand_not_the_grasp():
    hand = np.array([[0.5, 0.0, 0.4 + 0.08]])  # 8 cm behind the fingertips of a top-down EE at z = 0.4
    grasped = np.array([[0.5, 0.0, 0.4]])  # between the fingertips
    pose = make_pose(np.array([0.5, 0.0, 0.4]), Rotation.from_euler("x", 180, degrees=True))
    state = torch.from_numpy(np.r_[pose[:3, 3], Rotation.from_matrix(pose[:3, :3]).as_quat(), 1.0][None])
    observation = {
        CLOUD_KEY: np.concatenate([hand, grasped])[None],
        CLOUD_MASK_KEY: np.ones((1, 2), dtype=bool),
        "observation.state": state,
    }
    assert RemoveGripperStep().observation(observation)[CLOUD_MASK_KEY].tolist() == [[False, True]]


def test_robot_model_forward_kinematics_and_removal_match_the_simulator():
    env = BulletTabletopEnv("pick_and_lift", BulletTabletopConfig(obs_type="rgbd"))
    env.reset(seed=2)
    for action in env.scripted_actions()[:15]:
        env.step(action)
    robot = RobotModel(low_poly_panda_urdf(), list(JOINT_NAMES))
    joints = env.joint_positions()
    assert robot.link_pose(joints, "panda_grasptarget") == pytest.approx(env.robot.ee_pose(), abs=1e-4)
    surface = robot.surface_points(joints)
    assert not robot.away_from_robot(surface[::50], joints, 0.01).any()
    far = surface[::50] + np.array([0.0, 0.0, 2.0])
    assert robot.away_from_robot(far, joints, 0.01).all()
    with pytest.raises(ValueError, match="expects 9"):
        robot.surface_points(joints[:7])
    with pytest.raises(KeyError, match="no joints"):
        RobotModel(low_poly_panda_urdf(), ["elbow"])
    robot.close()
    env.close()
