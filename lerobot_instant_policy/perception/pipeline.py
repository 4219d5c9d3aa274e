"""``PerceptionConfig`` and the processor pipeline it builds: depth cameras → segmented ``observation.pointcloud``.

    crop to the workspace box → remove the table plane (RANSAC) → remove the robot (its links posed by the joint
    state, when a URDF is given; else a box around the EE pose) → resample to ``num_points``

preceded by ``StackCalibratedCamerasStep`` when the cameras come from a calibration file (datasets, real robots)
rather than from the observation itself (``bullet_tabletop`` in ``rgbd`` mode).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.processor import PolicyProcessorPipeline

from .steps import (
    JOINTS_KEY,
    CropWorkspaceStep,
    DepthToPointCloudStep,
    RemoveGripperStep,
    RemoveRobotStep,
    RemoveTablePlaneStep,
    ResamplePointCloudStep,
    StackCalibratedCamerasStep,
)


@dataclass
class PerceptionConfig:
    """Settings of the depth → segmented cloud pipeline (world frame, metres).

    ``calibration_path``: a calibration file (``perception.calibration``); ``None`` when the observation carries
    ``intrinsics`` and ``T_world_camera``. ``robot_urdf`` + ``robot_joint_names``: remove the robot's links posed by
    ``joint_key``; without a URDF a box around the EE (``observation.state``) is removed instead.
    """

    num_points: int = 2048
    calibration_path: str | None = None
    near: float = 0.05
    far: float = 3.0
    workspace_low: tuple[float, float, float] = (0.15, -0.5, -0.05)
    workspace_high: tuple[float, float, float] = (0.85, 0.5, 0.6)
    table_distance_threshold: float = 0.005
    robot_urdf: str | None = None
    robot_joint_names: list[str] = field(default_factory=list)
    joint_key: str = JOINTS_KEY
    robot_margin: float = 0.012
    min_points: int = 16
    seed: int = 0

    def __post_init__(self):
        if self.num_points <= 0 or self.min_points <= 0:
            raise ValueError("num_points and min_points must be positive")
        if not 0 < self.near < self.far:
            raise ValueError(f"need 0 < near < far, got near={self.near}, far={self.far}")
        if self.robot_urdf and not self.robot_joint_names:
            raise ValueError("robot_urdf needs robot_joint_names (the URDF joints of the joint state, in order)")

    def steps(self) -> list:
        steps = [StackCalibratedCamerasStep(self.calibration_path)] if self.calibration_path else []
        steps += [
            DepthToPointCloudStep(near=self.near, far=self.far),
            CropWorkspaceStep(low=tuple(self.workspace_low), high=tuple(self.workspace_high)),
            RemoveTablePlaneStep(distance_threshold=self.table_distance_threshold, seed=self.seed),
        ]
        if self.robot_urdf:
            steps.append(RemoveRobotStep(self.robot_urdf, list(self.robot_joint_names), self.robot_margin, self.joint_key))
        else:
            steps.append(RemoveGripperStep())
        steps.append(ResamplePointCloudStep(self.num_points, self.min_points, self.seed))
        return steps


def make_perception_pipeline(config: PerceptionConfig) -> PolicyProcessorPipeline:
    """A ``PolicyProcessorPipeline`` (batch dict in, batch dict out) of ``config.steps()``."""
    return PolicyProcessorPipeline(steps=config.steps(), name="instant_policy_perception")
