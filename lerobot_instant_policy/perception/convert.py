"""A LeRobot dataset of depth cameras and robot state → a dataset in the project's data contract.

Every frame's depth images go through the perception pipeline (:mod:`.pipeline`: back-projection with the
calibration, workspace crop, table-plane RANSAC, robot removal, resampling to ``num_points``); the EE pose comes
from the Cartesian state (``state_key``, already ``xyz, quaternion xyzw, gripper_open``, world frame) or, with
``ee_link``, from forward kinematics of ``urdf`` at the joint state. Actions are the dataset's own
(``action_source="dataset"``, the contract layout) or the next frame's EE pose and gripper (``"next_state"``, what any
recording allows). The output is what ``--policy.demo_root`` reads. Camera calibration comes from a calibration file
or from the dataset's depth features (``info.camera_calibration``); the one used is saved as
``OUT/meta/camera_calibration.json``. ``lerobot-ip-convert`` is the command line.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY, poses_from_vectors, vectors_from_poses
from .calibration import CameraCalibration, load_calibration, save_calibration


class ConversionError(ValueError):
    """The input dataset lacks what the conversion needs (keys, calibration, a valid state)."""


@dataclass
class ConvertSettings:
    """What :func:`convert` reads and how (see the module docstring; workspace corners in metres, world frame)."""

    input_root: Path
    input_repo_id: str
    out: Path
    repo_id: str
    calibration: Path | None = None
    num_points: int = 2048
    state_key: str = STATE_KEY
    action_source: str = "next_state"
    urdf: str | None = None
    joint_key: str | None = None
    joint_names: list[str] = field(default_factory=list)
    ee_link: str | None = None
    gripper_key: str | None = None
    gripper_index: int = -1
    gripper_open_above: float = 0.5
    workspace_low: tuple[float, float, float] = (0.15, -0.5, -0.05)
    workspace_high: tuple[float, float, float] = (0.85, 0.5, 0.6)
    overwrite: bool = False

    def __post_init__(self):
        if self.action_source not in ("next_state", "dataset"):
            raise ConversionError(f"action_source must be 'next_state' or 'dataset', got {self.action_source!r}")
        if (self.urdf is None) != (self.joint_key is None) or (self.urdf and not self.joint_names):
            raise ConversionError("--urdf, --joint-key and --joint-names go together (the robot and its joint state)")
        if self.ee_link and not self.urdf:
            raise ConversionError("--ee-link (EE pose by forward kinematics) needs --urdf, --joint-key, --joint-names")
        if self.ee_link and self.gripper_key is None:
            raise ConversionError("with --ee-link the gripper state needs --gripper-key and --gripper-index")


def convert(settings: ConvertSettings) -> dict:
    """Convert every episode of the input dataset; returns a summary (episodes, frames, output root)."""
    from lerobot.datasets import LeRobotDataset

    if not (settings.input_root / "meta" / "info.json").is_file():
        raise ConversionError(f"{settings.input_root} holds no LeRobot dataset (no meta/info.json)")
    source = LeRobotDataset(settings.input_repo_id, root=settings.input_root, depth_output_unit="m")
    cameras = _cameras(settings, source)
    needed = _needed_keys(settings, cameras, source.meta.features)

    if settings.out.exists():
        if not settings.overwrite:
            raise FileExistsError(f"{settings.out} already exists; pass --overwrite to replace it")
        shutil.rmtree(settings.out)
    calibration_file = settings.out.parent / f".{settings.out.name}.camera_calibration.json"
    settings.out.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(cameras, calibration_file)
    perception = _perception_pipeline(settings, calibration_file)
    robot = None
    if settings.ee_link:
        from .robot_model import RobotModel

        robot = RobotModel(settings.urdf, settings.joint_names)
    try:
        frames = _convert_episodes(source, settings, needed, perception, robot)
    except BaseException:
        shutil.rmtree(settings.out, ignore_errors=True)  # never leave a half-converted dataset behind
        raise
    finally:
        calibration_file.unlink(missing_ok=True)
        if robot is not None:
            robot.close()
    save_calibration(cameras, settings.out / "meta" / "camera_calibration.json")
    return {"root": str(settings.out), "episodes": source.meta.total_episodes, "frames": frames}


def _cameras(settings: ConvertSettings, source) -> list[CameraCalibration]:
    """The cameras of ``settings.calibration`` or of ``source``'s metadata, with the depth unit of every depth feature
    set to metres: LeRobot returns them in metres (``depth_output_unit="m"``), whatever unit they were stored in."""
    from .calibration import calibration_from_dataset_features

    if settings.calibration is not None:
        cameras = load_calibration(settings.calibration)
    else:
        cameras = calibration_from_dataset_features(source.meta.features)
    depth_keys = set(source.meta.depth_keys)
    return [
        type(camera).from_dict({**camera.to_dict(), "depth_unit": "m"}) if camera.depth_key in depth_keys else camera
        for camera in cameras
    ]


def _needed_keys(settings: ConvertSettings, cameras: list[CameraCalibration], features: dict) -> list[str]:
    """The dataset keys the conversion reads (depth, masks, state, joints, gripper, action), each checked to be in
    ``features``, and the Cartesian state checked to be ``(8,)`` unless the EE pose comes from kinematics."""
    needed = [camera.depth_key for camera in cameras] + [c.mask_key for c in cameras if c.mask_key]
    needed += [key for key in (settings.state_key, settings.joint_key, settings.gripper_key) if key]
    if settings.action_source == "dataset":
        needed.append(ACTION_KEY)
    missing = sorted({key for key in needed if key not in features})
    if missing:
        raise ConversionError(f"the dataset at {settings.input_root} lacks {missing}; it has {sorted(features)}")
    if not settings.ee_link:
        _check_cartesian_feature(features, settings.state_key)
    return needed


def _perception_pipeline(settings: ConvertSettings, calibration_file: Path):
    """The depth → segmented cloud pipeline of ``settings`` with the cameras of ``calibration_file``."""
    from .pipeline import PerceptionConfig, make_perception_pipeline

    return make_perception_pipeline(
        PerceptionConfig(
            num_points=settings.num_points,
            calibration_path=str(calibration_file),
            workspace_low=settings.workspace_low,
            workspace_high=settings.workspace_high,
            robot_urdf=settings.urdf,
            robot_joint_names=list(settings.joint_names),
            joint_key=settings.joint_key or "observation.joint_positions",
        )
    )


def _convert_episodes(source, settings: ConvertSettings, needed: list[str], perception, robot) -> int:
    """Write every episode of ``source`` through ``perception`` into a new dataset at ``settings.out``; returns
    the number of frames."""
    from ..data.lerobot_format import create_dataset, write_episode

    output = create_dataset(settings.repo_id, settings.out, fps=int(source.fps), num_points=settings.num_points)
    frames = 0
    for episode in source.meta.episodes:
        start, stop = int(episode["dataset_from_index"]), int(episode["dataset_to_index"])
        clouds, states, actions = [], [], []
        for index in range(start, stop):
            item = source[index]
            observation = {key: item[key][None] for key in needed if key != ACTION_KEY}
            clouds.append(perception(observation)[POINTCLOUD_KEY][0].numpy())
            states.append(_ee_state(item, settings, robot))
            if settings.action_source == "dataset":
                actions.append(_contract_vector(item[ACTION_KEY].numpy(), ACTION_KEY))
        states = np.stack(states).astype(np.float32)
        actions = np.stack(actions) if actions else np.concatenate([states[1:], states[-1:]])
        write_episode(output, np.stack(clouds), states, actions.astype(np.float32), episode["tasks"][0])
        frames += stop - start
    output.finalize()
    return frames


def _check_cartesian_feature(features: dict, key: str) -> None:
    """``ConversionError`` unless the feature ``key`` has the Cartesian state's shape ``(8,)``."""
    shape = tuple(features[key].get("shape", ()))
    if shape != (8,):
        raise ConversionError(
            f"{key!r} has shape {shape}: a Cartesian state must be (8,) = EE xyz (m), quaternion xyzw, gripper_open "
            "(world frame); for a joint state pass --urdf, --joint-key, --joint-names and --ee-link"
        )


def _contract_vector(vector: np.ndarray, name: str) -> np.ndarray:
    """``vector (8,)`` checked to be a pose (a unit quaternion xyzw) and a gripper in [0, 1], written back by the
    contract's codec (quaternion normalised, ``w ≥ 0``)."""
    vector = np.asarray(vector, dtype=np.float64)
    if not np.all(np.isfinite(vector)) or abs(np.linalg.norm(vector[3:7]) - 1.0) > 1e-2:
        raise ConversionError(f"{name} {vector.tolist()} is not EE xyz + a unit quaternion xyzw + gripper")
    if not 0.0 <= vector[7] <= 1.0:
        raise ConversionError(f"{name} gripper {vector[7]} must be 1 open / 0 closed (map it with --gripper-*)")
    return vectors_from_poses(*poses_from_vectors(vector))


def _ee_state(item: dict, settings: ConvertSettings, robot) -> np.ndarray:
    """The contract's EE state ``(8,)`` of one dataset row: its Cartesian state, or (with ``robot``) the forward
    kinematics of ``settings.ee_link`` at its joints and the gripper open at or above ``gripper_open_above``."""
    if robot is None:
        return _contract_vector(item[settings.state_key].numpy(), settings.state_key)
    joints = item[settings.joint_key].numpy()[: len(settings.joint_names)]
    gripper_value = float(item[settings.gripper_key].numpy().reshape(-1)[settings.gripper_index])
    return vectors_from_poses(robot.link_pose(joints, settings.ee_link), gripper_value >= settings.gripper_open_above)
