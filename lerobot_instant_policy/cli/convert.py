"""``lerobot-ip-convert``: a LeRobot dataset of depth cameras and robot state → the project's data contract.

    lerobot-ip-convert --input demos/rgbd --input-repo-id local/rgbd --out demos/converted --repo-id local/converted
    lerobot-ip-convert ... --calibration calib.json                      (cameras from a file, docs/deployment.md)
    lerobot-ip-convert ... --urdf robot.urdf --joint-key observation.state --joint-names j1,j2,... --ee-link tcp \\
        --gripper-key observation.state --gripper-index 6 --gripper-open-above 0.5

Every frame's depth images go through the perception pipeline (``perception.pipeline``: back-projection with the
calibration, workspace crop, table-plane RANSAC, robot removal, resampling to ``--num-points``); the EE pose comes
from the Cartesian state (``--state-key``, already ``xyz, quaternion xyzw, gripper_open``) or, with ``--ee-link``,
from forward kinematics of ``--urdf`` at the joint state. Actions are the dataset's own (``--action-source
dataset``, the contract layout) or the next frame's EE pose and gripper (``next_state``, what any recording
allows). The output is what ``--policy.demo_root`` reads. Camera calibration comes from ``--calibration`` or from
the dataset's depth features (``info.camera_calibration``); the one used is saved as
``OUT/meta/camera_calibration.json``.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY, poses_from_vectors, vectors_from_poses
from ..perception.calibration import CalibrationError, load_calibration, save_calibration


class ConversionError(ValueError):
    """The input dataset lacks what the conversion needs (keys, calibration, a valid state)."""


@dataclass
class ConvertSettings:
    """What ``convert`` reads and how (see the module docstring for the options)."""

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

    from ..perception.calibration import calibration_from_dataset_features
    from ..perception.pipeline import PerceptionConfig, make_perception_pipeline

    if not (settings.input_root / "meta" / "info.json").is_file():
        raise ConversionError(f"{settings.input_root} holds no LeRobot dataset (no meta/info.json)")
    source = LeRobotDataset(settings.input_repo_id, root=settings.input_root, depth_output_unit="m")
    features = source.meta.features
    if settings.calibration is not None:
        cameras = load_calibration(settings.calibration)
    else:
        cameras = calibration_from_dataset_features(features)
    depth_keys = set(source.meta.depth_keys)
    # LeRobot returns its depth features in metres (depth_output_unit="m"), whatever unit they were stored in
    cameras = [
        type(camera).from_dict({**camera.to_dict(), "depth_unit": "m"}) if camera.depth_key in depth_keys else camera
        for camera in cameras
    ]
    needed = [camera.depth_key for camera in cameras] + [c.mask_key for c in cameras if c.mask_key]
    needed += [key for key in (settings.state_key, settings.joint_key, settings.gripper_key) if key]
    if settings.action_source == "dataset":
        needed.append(ACTION_KEY)
    missing = sorted({key for key in needed if key not in features})
    if missing:
        raise ConversionError(f"the dataset at {settings.input_root} lacks {missing}; it has {sorted(features)}")
    if not settings.ee_link:
        _check_cartesian_feature(features, settings.state_key)

    if settings.out.exists():
        if not settings.overwrite:
            raise FileExistsError(f"{settings.out} already exists; pass --overwrite to replace it")
        shutil.rmtree(settings.out)
    calibration_file = settings.out.parent / f".{settings.out.name}.camera_calibration.json"
    settings.out.parent.mkdir(parents=True, exist_ok=True)
    save_calibration(cameras, calibration_file)
    perception = make_perception_pipeline(
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
    robot = None
    if settings.ee_link:
        from ..perception.robot_model import RobotModel

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
    if robot is None:
        return _contract_vector(item[settings.state_key].numpy(), settings.state_key)
    joints = item[settings.joint_key].numpy()[: len(settings.joint_names)]
    gripper_value = float(item[settings.gripper_key].numpy().reshape(-1)[settings.gripper_index])
    return vectors_from_poses(robot.link_pose(joints, settings.ee_link), gripper_value >= settings.gripper_open_above)


def _floats(text: str) -> tuple[float, float, float]:
    values = tuple(float(x) for x in text.split(","))
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-convert", description=__doc__.split("\n\n")[0])
    parser.add_argument("--input", type=Path, required=True, help="root of the input LeRobot dataset")
    parser.add_argument("--input-repo-id", required=True)
    parser.add_argument("--out", type=Path, required=True, help="root of the converted dataset to create")
    parser.add_argument("--repo-id", required=True)
    parser.add_argument("--calibration", type=Path, help="camera calibration JSON (default: the dataset's metadata)")
    parser.add_argument("--num-points", type=int, default=2048)
    parser.add_argument("--state-key", default=STATE_KEY, help="Cartesian EE state (8,)")
    parser.add_argument("--action-source", choices=("next_state", "dataset"), default="next_state")
    parser.add_argument("--urdf", help="robot URDF: removes the robot's links from the clouds (and --ee-link: FK)")
    parser.add_argument("--joint-key", help="the joint state key (first len(--joint-names) entries are used)")
    parser.add_argument("--joint-names", type=lambda text: text.split(","), default=[], help="URDF joint names")
    parser.add_argument("--ee-link", help="URDF link of the EE frame: EE pose by forward kinematics")
    parser.add_argument("--gripper-key", help="key holding the gripper value (with --ee-link)")
    parser.add_argument("--gripper-index", type=int, default=-1)
    parser.add_argument("--gripper-open-above", type=float, default=0.5, help="gripper value at or above: open")
    parser.add_argument("--workspace-low", type=_floats, default=(0.15, -0.5, -0.05), help="x,y,z (m, world)")
    parser.add_argument("--workspace-high", type=_floats, default=(0.85, 0.5, 0.6), help="x,y,z (m, world)")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    from ..perception.depth import DepthUnitError
    from ..perception.segmentation import EmptyPointCloudError

    try:
        settings = ConvertSettings(
            input_root=args.input,
            input_repo_id=args.input_repo_id,
            out=args.out,
            repo_id=args.repo_id,
            calibration=args.calibration,
            num_points=args.num_points,
            state_key=args.state_key,
            action_source=args.action_source,
            urdf=args.urdf,
            joint_key=args.joint_key,
            joint_names=args.joint_names,
            ee_link=args.ee_link,
            gripper_key=args.gripper_key,
            gripper_index=args.gripper_index,
            gripper_open_above=args.gripper_open_above,
            workspace_low=args.workspace_low,
            workspace_high=args.workspace_high,
            overwrite=args.overwrite,
        )
        summary = convert(settings)
    except (ConversionError, CalibrationError, DepthUnitError, EmptyPointCloudError, FileExistsError, KeyError) as error:
        print(f"lerobot-ip-convert: error: {error}", file=sys.stderr)
        return 2
    print(f"converted {summary['episodes']} episodes ({summary['frames']} frames) to {summary['root']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
