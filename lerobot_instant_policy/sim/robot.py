"""The Franka Panda of ``pybullet_data`` with an end-effector frame, inverse kinematics and a binary gripper.

EE frame (the project's convention, ``geometry.se3.look_rotation``): the ``panda_grasptarget`` link, 0.105 m
from the hand flange, i.e. between the fingertips. Its z axis is the approach direction (out of the hand),
its y axis the finger-opening axis. ``agent_pos`` and actions are poses of this frame in the world frame.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet
import pybullet_data

from ..geometry.se3 import pose_from_pos_quat

PANDA_URDF = "franka_panda/panda.urdf"
EE_LINK_NAME = "panda_grasptarget"
FINGER_JOINT_NAMES = ("panda_finger_joint1", "panda_finger_joint2")
JOINT_NAMES = tuple(f"panda_joint{index}" for index in range(1, 8)) + FINGER_JOINT_NAMES  # of ``joint_positions``
ARM_DOF = 7
FINGER_OPEN = 0.04
FINGER_CLOSED = 0.0


@dataclass
class RobotConfig:
    """Joint-space settings of the simulated Panda."""

    home_joints: tuple[float, ...] = (0.0, -0.35, 0.0, -2.3, 0.0, 1.95, 0.785)
    arm_forces: tuple[float, ...] = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
    arm_position_gain: float = 0.3
    finger_force: float = 60.0
    finger_lateral_friction: float = 2.0
    ik_iterations: int = 100
    ik_threshold: float = 1e-6


def low_poly_panda_urdf() -> str:
    """Path of a copy of ``panda.urdf`` that draws the links with their collision meshes.

    The visual meshes have about 100 times more triangles; with them, rendering the three segmentation cameras
    costs ten times as much. Written once per machine to the temporary directory (mesh paths absolute).
    """
    source = Path(pybullet_data.getDataPath()) / PANDA_URDF
    meshes = (source.parent / "meshes" / "collision").as_posix() + "/"
    text = source.read_text().replace("package://meshes/visual/", meshes).replace("package://meshes/collision/", meshes)
    digest = hashlib.sha1(text.encode()).hexdigest()[:12]
    target = Path(tempfile.gettempdir()) / f"lerobot_ip_panda_low_poly_{digest}.urdf"
    if not target.exists():
        partial = target.with_suffix(f".{os.getpid()}.tmp")
        partial.write_text(text)
        partial.replace(target)
    return str(target)


class PandaRobot:
    """A Panda loaded into pybullet client ``client`` with its base at the world origin."""

    def __init__(self, client: int, config: RobotConfig | None = None):
        self.client = client
        self.config = config or RobotConfig()
        self.body = pybullet.loadURDF(
            low_poly_panda_urdf(),
            basePosition=(0.0, 0.0, 0.0),
            useFixedBase=True,
            flags=pybullet.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT,
            physicsClientId=client,
        )
        names = {}
        self._movable: list[int] = []
        lower, upper = [], []
        for joint in range(pybullet.getNumJoints(self.body, physicsClientId=client)):
            info = pybullet.getJointInfo(self.body, joint, physicsClientId=client)
            names[info[1].decode()] = joint
            names[info[12].decode()] = joint
            if info[2] != pybullet.JOINT_FIXED:
                self._movable.append(joint)
                lower.append(info[8])
                upper.append(info[9])
        self.ee_link = names[EE_LINK_NAME]
        self.finger_joints = tuple(names[name] for name in FINGER_JOINT_NAMES)
        self.arm_joints = tuple(self._movable[:ARM_DOF])
        self._lower = np.array(lower)
        self._upper = np.array(upper)
        for finger in self.finger_joints:
            pybullet.changeDynamics(
                self.body, finger, lateralFriction=self.config.finger_lateral_friction, physicsClientId=client
            )
        self.gripper_open = True

    @property
    def finger_links(self) -> tuple[int, ...]:
        """Link indices of the two fingers (a joint's child link has the joint's index)."""
        return self.finger_joints

    def reset(self) -> None:
        """Joints to the home configuration, gripper open, motors holding that state."""
        rest = self._rest_positions(FINGER_OPEN)
        for joint, value in zip(self._movable, rest, strict=True):
            pybullet.resetJointState(self.body, joint, value, 0.0, physicsClientId=self.client)
        self.gripper_open = True
        self._command_arm(np.asarray(self.config.home_joints))
        self.command_gripper(True)

    def ee_pose(self) -> np.ndarray:
        """``T_world_ee (4, 4)``: the EE frame in the world frame."""
        state = pybullet.getLinkState(
            self.body, self.ee_link, computeForwardKinematics=True, physicsClientId=self.client
        )
        return pose_from_pos_quat(np.asarray(state[4]), np.asarray(state[5]))

    def joint_positions(self) -> np.ndarray:
        """``(9,)`` positions of the movable joints: 7 arm joints (rad), 2 finger joints (m)."""
        states = pybullet.getJointStates(self.body, self._movable, physicsClientId=self.client)
        return np.array([state[0] for state in states])

    def finger_opening(self) -> float:
        """Distance between the fingers (m), 0.08 fully open."""
        return float(
            sum(
                pybullet.getJointState(self.body, joint, physicsClientId=self.client)[0] for joint in self.finger_joints
            )
        )

    def command_pose(self, position: np.ndarray, quat_xyzw: np.ndarray) -> None:
        """Set the arm's joint targets to the IK solution for EE ``position (3,)``/``quat_xyzw (4,)`` (world).

        The null-space rest pose is the current configuration, which keeps the solution close to it (accurate
        to about a millimetre for the bounded steps the env commands).
        """
        current = [pybullet.getJointState(self.body, joint, physicsClientId=self.client)[0] for joint in self._movable]
        solution = pybullet.calculateInverseKinematics(
            self.body,
            self.ee_link,
            targetPosition=[float(value) for value in position],
            targetOrientation=[float(value) for value in quat_xyzw],
            lowerLimits=self._lower.tolist(),
            upperLimits=self._upper.tolist(),
            jointRanges=(self._upper - self._lower).tolist(),
            restPoses=current,
            maxNumIterations=self.config.ik_iterations,
            residualThreshold=self.config.ik_threshold,
            physicsClientId=self.client,
        )
        self._command_arm(np.clip(np.asarray(solution[:ARM_DOF]), self._lower[:ARM_DOF], self._upper[:ARM_DOF]))

    def command_gripper(self, open_: bool) -> None:
        """Open (``True``) or close the fingers with the configured force."""
        self.gripper_open = bool(open_)
        target = FINGER_OPEN if self.gripper_open else FINGER_CLOSED
        pybullet.setJointMotorControlArray(
            self.body,
            list(self.finger_joints),
            pybullet.POSITION_CONTROL,
            targetPositions=[target, target],
            forces=[self.config.finger_force] * 2,
            physicsClientId=self.client,
        )

    def _command_arm(self, joints: np.ndarray) -> None:
        pybullet.setJointMotorControlArray(
            self.body,
            list(self.arm_joints),
            pybullet.POSITION_CONTROL,
            targetPositions=joints.tolist(),
            forces=list(self.config.arm_forces),
            positionGains=[self.config.arm_position_gain] * ARM_DOF,
            physicsClientId=self.client,
        )

    def _rest_positions(self, finger: float) -> np.ndarray:
        return np.concatenate([np.asarray(self.config.home_joints), [finger, finger]])
