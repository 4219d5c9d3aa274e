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
``OUT/meta/camera_calibration.json``. The conversion itself is :mod:`lerobot_instant_policy.perception.convert`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..contract import STATE_KEY
from ..perception.calibration import CalibrationError
from ..perception.convert import ConversionError, ConvertSettings, convert
from ..perception.depth import DepthUnitError
from ..perception.segmentation import EmptyPointCloudError
from .arguments import xyz


def build_parser() -> argparse.ArgumentParser:
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
    parser.add_argument("--workspace-low", type=xyz, default=(0.15, -0.5, -0.05), help="x,y,z (m, world)")
    parser.add_argument("--workspace-high", type=xyz, default=(0.85, 0.5, 0.6), help="x,y,z (m, world)")
    parser.add_argument("--overwrite", action="store_true")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
