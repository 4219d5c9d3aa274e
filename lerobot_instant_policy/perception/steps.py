"""Depth cameras → a segmented, fixed-size world-frame point cloud, as LeRobot ``ProcessorStep``s.

The same steps convert a recorded dataset offline (``lerobot-ip-convert``) and run online before
``select_action`` (``bullet_tabletop --env.obs_type=rgbd`` puts them in its env preprocessor). Every step works
on batched observations (leading batch dimension ``B``); tensors or numpy arrays are accepted.

Keys (``observation.`` prefix):
    ``depth (B, C, H, W)`` metres, ``intrinsics (B, C, 3, 3)``, ``T_world_camera (B, C, 4, 4)``: C cameras;
    ``object_mask (B, C, H, W)``: optional user masks (nonzero = task object);
    ``pointcloud (B, C*H*W, 3)`` + ``pointcloud_mask (B, C*H*W)`` bool: the fused cloud while it is segmented,
    each segmentation step clearing the mask of the points it removes;
    ``pointcloud (B, N, 3)`` float32 after ``ResamplePointCloudStep`` (the data contract, world frame).
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry

from ..contract import POINTCLOUD_KEY, STATE_KEY, poses_from_vectors
from ..geometry.sampling import resample_points
from .calibration import CalibrationError, check_extrinsics, check_intrinsics, load_calibration
from .depth import DepthRange, backproject, check_depth_metres
from .robot_model import RobotModel
from .segmentation import EmptyPointCloudError, above_plane, fit_horizontal_plane, inside_box, outside_gripper_box

DEPTH_KEY = "observation.depth"
INTRINSICS_KEY = "observation.intrinsics"
EXTRINSICS_KEY = "observation.T_world_camera"
OBJECT_MASK_KEY = "observation.object_mask"
JOINTS_KEY = "observation.joint_positions"
CLOUD_MASK_KEY = "observation.pointcloud_mask"
CAMERA_KEYS = (DEPTH_KEY, INTRINSICS_KEY, EXTRINSICS_KEY, OBJECT_MASK_KEY)


def to_numpy(value) -> np.ndarray:
    return value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else np.asarray(value)


def require(observation: dict, key: str, step: str, ndim: int, shape_text: str) -> np.ndarray:
    """``observation[key]`` as numpy with ``ndim`` dimensions, or a ``KeyError``/``ValueError`` naming ``step``."""
    if key not in observation:
        raise KeyError(f"{step} needs {key!r} {shape_text} in the observation, got keys {sorted(observation)}")
    value = to_numpy(observation[key])
    if value.ndim != ndim:
        raise ValueError(f"{step}: {key!r} must have shape {shape_text}, got {tuple(value.shape)}")
    return value


class CloudSegmentationStep(ObservationProcessorStep):
    """A step that clears ``pointcloud_mask`` where ``keep(points (P, 3), observation, row)`` is False."""

    def observation(self, observation: dict) -> dict:
        step = type(self).__name__
        points = require(observation, POINTCLOUD_KEY, step, 3, "(B, P, 3)")
        mask = require(observation, CLOUD_MASK_KEY, step, 2, "(B, P)").astype(bool)
        for row in range(len(points)):
            selected = np.flatnonzero(mask[row])
            mask[row, selected] = self.keep(points[row, selected], observation, row)
        return {**observation, CLOUD_MASK_KEY: mask}

    @abstractmethod
    def keep(self, points: np.ndarray, observation: dict, row: int) -> np.ndarray:
        """``(P,)`` bool: which of one row's remaining ``points (P, 3)`` (world frame) the step keeps."""

    def get_config(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.__dataclass_fields__ if not name.startswith("_")}

    def transform_features(self, features):
        return features


@ProcessorStepRegistry.register(name="ip_stack_calibrated_cameras")
@dataclass
class StackCalibratedCamerasStep(ObservationProcessorStep):
    """Per-camera depth keys + a calibration file → the stacked ``depth``, ``intrinsics``, ``T_world_camera``
    (and ``object_mask`` when every camera names a ``mask_key``) that ``DepthToPointCloudStep`` reads.

    ``calibration_path``: the JSON file of ``perception.calibration``. Each camera's depth ``(B, H, W)`` or
    ``(B, 1, H, W)`` is scaled from its ``depth_unit`` to metres; its size must be the calibrated one.
    """

    calibration_path: str = ""

    def __post_init__(self):
        self._cameras = load_calibration(self.calibration_path)
        sizes = {(camera.height, camera.width) for camera in self._cameras}
        if len(sizes) != 1:
            raise CalibrationError(f"{self.calibration_path}: cameras must share one image size, got {sorted(sizes)}")

    def observation(self, observation: dict) -> dict:
        depths, masks = [], []
        for camera in self._cameras:
            if camera.depth_key not in observation:
                raise KeyError(f"camera {camera.name!r}: no depth {camera.depth_key!r} in the observation {sorted(observation)}")
            depth = to_numpy(observation[camera.depth_key])
            if depth.ndim not in (3, 4) or (depth.ndim == 4 and depth.shape[1] != 1):
                raise ValueError(f"camera {camera.name!r}: depth must be (B, H, W) or (B, 1, H, W), got {depth.shape}")
            depth = depth.reshape(len(depth), *depth.shape[-2:]).astype(np.float32)
            if depth.shape[1:] != (camera.height, camera.width):
                raise CalibrationError(
                    f"camera {camera.name!r}: depth image is {depth.shape[2]}x{depth.shape[1]} but its calibration is "
                    f"for {camera.width}x{camera.height}"
                )
            depths.append(depth * camera.metres_per_unit)
            if camera.mask_key:
                mask = to_numpy(observation[camera.mask_key])
                masks.append(mask.reshape(len(mask), *mask.shape[-2:]) != 0)
        batch = len(depths[0])
        stacked = {
            DEPTH_KEY: np.stack(depths, axis=1),
            INTRINSICS_KEY: np.broadcast_to(np.stack([c.intrinsics for c in self._cameras]), (batch, len(depths), 3, 3)),
            EXTRINSICS_KEY: np.broadcast_to(np.stack([c.pose for c in self._cameras]), (batch, len(depths), 4, 4)),
        }
        if len(masks) == len(self._cameras):
            stacked[OBJECT_MASK_KEY] = np.stack(masks, axis=1)
        used = {camera.depth_key for camera in self._cameras} | {c.mask_key for c in self._cameras if c.mask_key}
        return {**{key: value for key, value in observation.items() if key not in used}, **stacked}

    def get_config(self) -> dict[str, Any]:
        return {"calibration_path": self.calibration_path}

    def transform_features(self, features):
        return features


@ProcessorStepRegistry.register(name="ip_depth_to_pointcloud")
@dataclass
class DepthToPointCloudStep(ObservationProcessorStep):
    """``depth``, ``intrinsics``, ``T_world_camera`` (and ``object_mask``) → the fused world-frame ``pointcloud
    (B, C*H*W, 3)`` and its ``pointcloud_mask`` (valid returns inside ``[near, far]`` m, within the user mask).

    Raises ``CalibrationError`` for missing, non-finite or inconsistent camera parameters and ``DepthUnitError``
    for depth that cannot be metres. The camera keys are removed from the observation.
    """

    near: float = 0.05
    far: float = 3.0
    implausible: float = 20.0

    def observation(self, observation: dict) -> dict:
        step = type(self).__name__
        missing = [key for key in (INTRINSICS_KEY, EXTRINSICS_KEY) if key not in observation]
        if missing:
            raise CalibrationError(f"{step}: the observation has depth but no camera parameters {missing}")
        depth = require(observation, DEPTH_KEY, step, 4, "(B, C, H, W)")
        intrinsics = require(observation, INTRINSICS_KEY, step, 4, "(B, C, 3, 3)").astype(np.float64)
        extrinsics = require(observation, EXTRINSICS_KEY, step, 4, "(B, C, 4, 4)").astype(np.float64)
        batch, cameras, height, width = depth.shape
        if intrinsics.shape[:2] != (batch, cameras) or extrinsics.shape[:2] != (batch, cameras):
            raise CalibrationError(
                f"{step}: {cameras} depth images but intrinsics for {intrinsics.shape[1]} and extrinsics for "
                f"{extrinsics.shape[1]} cameras"
            )
        user_mask = to_numpy(observation[OBJECT_MASK_KEY]) != 0 if OBJECT_MASK_KEY in observation else None
        depth_range = DepthRange(self.near, self.far, self.implausible)
        points = np.zeros((batch, cameras * height * width, 3), dtype=np.float32)
        mask = np.zeros((batch, cameras * height * width), dtype=bool)
        for row in range(batch):
            for camera in range(cameras):
                where = f"camera {camera}"
                check_intrinsics(intrinsics[row, camera], width, height, where)
                check_extrinsics(extrinsics[row, camera], where)
                check_depth_metres(depth[row, camera], depth_range, where)
                span = slice(camera * height * width, (camera + 1) * height * width)
                points[row, span], mask[row, span] = backproject(
                    depth[row, camera], intrinsics[row, camera], extrinsics[row, camera], depth_range
                )
                if user_mask is not None:
                    mask[row, span] &= user_mask[row, camera].reshape(-1)
        kept = {key: value for key, value in observation.items() if key not in CAMERA_KEYS}
        return {**kept, POINTCLOUD_KEY: points, CLOUD_MASK_KEY: mask}

    def get_config(self) -> dict[str, Any]:
        return {"near": self.near, "far": self.far, "implausible": self.implausible}

    def transform_features(self, features):
        observation = {key: value for key, value in features.get(PipelineFeatureType.OBSERVATION, {}).items()
                       if key not in CAMERA_KEYS}
        return {**features, PipelineFeatureType.OBSERVATION: observation}


@ProcessorStepRegistry.register(name="ip_crop_workspace")
@dataclass
class CropWorkspaceStep(CloudSegmentationStep):
    """Keep the points inside the world-frame box ``[low, high]`` (m)."""

    low: tuple[float, float, float] = (0.15, -0.5, -0.05)
    high: tuple[float, float, float] = (0.85, 0.5, 0.6)

    def keep(self, points, observation, row):
        return inside_box(points, np.asarray(self.low), np.asarray(self.high))


@ProcessorStepRegistry.register(name="ip_remove_table_plane")
@dataclass
class RemoveTablePlaneStep(CloudSegmentationStep):
    """Fit the table as the largest near-horizontal plane (RANSAC) and keep only the points more than
    ``distance_threshold`` (m) above it. A plane holding less than ``min_inlier_fraction`` of the points is not
    taken for the table (nothing is removed)."""

    distance_threshold: float = 0.008
    iterations: int = 200
    max_tilt_deg: float = 20.0
    min_inlier_fraction: float = 0.2
    seed: int = 0

    def keep(self, points, observation, row):
        plane = fit_horizontal_plane(
            points, np.random.default_rng(self.seed), self.distance_threshold, self.iterations, self.max_tilt_deg
        )
        if plane is None or plane[2] < self.min_inlier_fraction:
            return np.ones(len(points), dtype=bool)
        return above_plane(points, plane[0], plane[1], self.distance_threshold)


@ProcessorStepRegistry.register(name="ip_remove_robot")
@dataclass
class RemoveRobotStep(CloudSegmentationStep):
    """Remove points within ``margin`` (m) of the robot's links, posed by ``joint_positions (B, J)`` through the
    URDF at ``urdf_path`` (``joint_names``: the URDF joints of the state vector, in order)."""

    urdf_path: str = ""
    joint_names: list[str] = field(default_factory=list)
    margin: float = 0.012
    joint_key: str = JOINTS_KEY

    def __post_init__(self):
        self._robot = RobotModel(self.urdf_path, self.joint_names)

    def keep(self, points, observation, row):
        joints = require(observation, self.joint_key, type(self).__name__, 2, "(B, J)")[row]
        return self._robot.away_from_robot(points, joints, self.margin)


@ProcessorStepRegistry.register(name="ip_remove_gripper")
@dataclass
class RemoveGripperStep(CloudSegmentationStep):
    """Remove points inside the box ``[low, high]`` of the EE frame (the hand), posed by ``observation.state``
    (EE xyz, quaternion xyzw, gripper): robot removal for datasets with a Cartesian state and no joint state.

    The default box covers a Panda hand above the fingertips (EE z is the approach axis); the space between the
    fingertips is kept, where a grasped object is."""

    low: tuple[float, float, float] = (-0.045, -0.12, -0.2)
    high: tuple[float, float, float] = (0.045, 0.12, -0.035)

    def keep(self, points, observation, row):
        T_world_ee, _ = poses_from_vectors(require(observation, STATE_KEY, type(self).__name__, 2, "(B, 8)")[row])
        return outside_gripper_box(points, T_world_ee, np.asarray(self.low), np.asarray(self.high))


@ProcessorStepRegistry.register(name="ip_resample_pointcloud")
@dataclass
class ResamplePointCloudStep(ObservationProcessorStep):
    """The kept points of each row → ``pointcloud (B, num_points, 3)`` float32 tensor (farthest-point sampling,
    or repeats when fewer), dropping ``pointcloud_mask``. Fewer than ``min_points`` kept points raise
    ``EmptyPointCloudError``: an action is never computed from an empty or near-empty cloud."""

    num_points: int = 2048
    min_points: int = 16
    seed: int = 0

    def observation(self, observation: dict) -> dict:
        step = type(self).__name__
        points = require(observation, POINTCLOUD_KEY, step, 3, "(B, P, 3)")
        mask = require(observation, CLOUD_MASK_KEY, step, 2, "(B, P)").astype(bool)
        rng = np.random.default_rng(self.seed)
        clouds = []
        for row in range(len(points)):
            kept = points[row, mask[row]]
            if len(kept) < self.min_points:
                raise EmptyPointCloudError(
                    f"only {len(kept)} points of the task objects are left after segmentation (batch row {row}; at "
                    f"least {self.min_points} needed): check the camera calibration, the workspace box and that the "
                    "objects are in view"
                )
            clouds.append(resample_points(kept, self.num_points, rng))
        kept_keys = {key: value for key, value in observation.items() if key != CLOUD_MASK_KEY}
        return {**kept_keys, POINTCLOUD_KEY: torch.from_numpy(np.stack(clouds))}

    def get_config(self) -> dict[str, Any]:
        return {"num_points": self.num_points, "min_points": self.min_points, "seed": self.seed}

    def transform_features(self, features):
        observation = dict(features.get(PipelineFeatureType.OBSERVATION, {}))
        observation[POINTCLOUD_KEY] = PolicyFeature(type=FeatureType.STATE, shape=(self.num_points, 3))
        return {**features, PipelineFeatureType.OBSERVATION: observation}
