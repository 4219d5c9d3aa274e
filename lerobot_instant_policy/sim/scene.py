"""The tabletop scene a task builds its objects in: object factories and state queries in one pybullet client.

World frame: the table top is the plane z = 0, the robot base stands at the origin, the workspace lies in
front of it (+x). Every body created through a ``Scene`` factory is a *task object*: it is part of the
observed point cloud. The table and the robot are not.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from ..geometry.se3 import make_pose, pose_from_pos_quat
from .robot import PandaRobot

TABLE_HALF_EXTENTS = (0.55, 0.65, 0.02)
TABLE_CENTRE = (0.45, 0.0, -0.02)


@dataclass
class Part:
    """One primitive of a compound rigid object, placed at ``offset`` in the object frame (m, rad about z)."""

    shape: str
    size: tuple[float, ...]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0

    def __post_init__(self):
        expected = {"box": 3, "cylinder": 2}
        if self.shape not in expected:
            raise ValueError(f"Part.shape must be one of {sorted(expected)}, got {self.shape!r}")
        if len(self.size) != expected[self.shape] or min(self.size) <= 0:
            raise ValueError(
                f"a {self.shape} part needs {expected[self.shape]} positive sizes "
                "(box: half extents; cylinder: radius, height)"
            )


def asset_path(filename: str) -> str:
    """Absolute path of a file in ``lerobot_instant_policy/assets/sim``."""
    return str(resources.files("lerobot_instant_policy") / "assets" / "sim" / filename)


def yaw_quat(yaw: float) -> list[float]:
    """Quaternion (xyzw) of a rotation by ``yaw`` rad about the world z axis."""
    return Rotation.from_euler("z", yaw).as_quat().tolist()


class Scene:
    """Task objects in pybullet client ``client``, next to ``robot``."""

    def __init__(self, client: int, robot: PandaRobot):
        self.client = client
        self.robot = robot
        self.object_bodies: list[int] = []
        self._marker_radius: dict[int, float] = {}

    # --- factories -------------------------------------------------------------------------------------

    def add_box(
        self,
        half_extents: tuple[float, float, float],
        position: tuple[float, float, float] | np.ndarray,
        yaw: float = 0.0,
        mass: float = 0.1,
        rgba: tuple[float, float, float, float] = (0.8, 0.3, 0.2, 1.0),
        friction: float = 1.0,
    ) -> int:
        """A box with its frame at its centre; ``mass`` 0 makes it static."""
        return self.add_compound([Part("box", tuple(half_extents))], position, yaw, mass, rgba, friction)

    def add_compound(
        self,
        parts: list[Part],
        position: tuple[float, float, float] | np.ndarray,
        yaw: float = 0.0,
        mass: float = 0.1,
        rgba: tuple[float, float, float, float] = (0.8, 0.3, 0.2, 1.0),
        friction: float = 1.0,
        collision: bool = True,
    ) -> int:
        """A rigid body made of boxes and cylinders, its frame at ``position`` turned by ``yaw`` about z.

        ``collision=False`` gives a visual-only marker (seen by the cameras, felt by nothing).
        """
        kwargs = dict(
            shapeTypes=[pybullet.GEOM_BOX if part.shape == "box" else pybullet.GEOM_CYLINDER for part in parts],
            halfExtents=[list(part.size) if part.shape == "box" else [0.0, 0.0, 0.0] for part in parts],
            radii=[part.size[0] if part.shape == "cylinder" else 0.0 for part in parts],
            lengths=[part.size[1] if part.shape == "cylinder" else 0.0 for part in parts],
        )
        frames = dict(
            positions=[list(part.offset) for part in parts], orientations=[yaw_quat(part.yaw) for part in parts]
        )
        visual = pybullet.createVisualShapeArray(
            **kwargs,
            rgbaColors=[list(rgba)] * len(parts),
            visualFramePositions=frames["positions"],
            visualFrameOrientations=frames["orientations"],
            physicsClientId=self.client,
        )
        collision_shape = -1
        if collision:
            collision_shape = pybullet.createCollisionShapeArray(
                **kwargs,
                collisionFramePositions=frames["positions"],
                collisionFrameOrientations=frames["orientations"],
                physicsClientId=self.client,
            )
        body = pybullet.createMultiBody(
            baseMass=mass if collision else 0.0,
            baseCollisionShapeIndex=collision_shape,
            baseVisualShapeIndex=visual,
            basePosition=[float(value) for value in position],
            baseOrientation=yaw_quat(yaw),
            physicsClientId=self.client,
        )
        if collision:
            pybullet.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=self.client)
        else:
            self._marker_radius[body] = max(np.linalg.norm(part.offset) + np.linalg.norm(part.size) for part in parts)
        self.object_bodies.append(body)
        return body

    def load_urdf(
        self, filename: str, position: tuple[float, float, float] | np.ndarray, yaw: float = 0.0, fixed: bool = True
    ) -> int:
        """An articulated object from ``assets/sim/filename`` (or an absolute path); every joint starts free."""
        path = filename if filename.startswith("/") else asset_path(filename)
        body = pybullet.loadURDF(
            path,
            basePosition=[float(value) for value in position],
            baseOrientation=yaw_quat(yaw),
            useFixedBase=fixed,
            physicsClientId=self.client,
        )
        for joint in range(pybullet.getNumJoints(body, physicsClientId=self.client)):
            self.set_joint_friction(body, joint, 0.0)
        self.object_bodies.append(body)
        return body

    def object_corners(self) -> np.ndarray:
        """Corners ``(C, 3)`` (world frame) of boxes that bound every task object (one box per link)."""
        corners = []
        for body in self.object_bodies:
            if body in self._marker_radius:
                centre, radius = self.pose(body)[:3, 3], self._marker_radius[body]
                boxes = [(centre - radius, centre + radius)]
            else:
                links = range(-1, pybullet.getNumJoints(body, physicsClientId=self.client))
                boxes = [pybullet.getAABB(body, link, physicsClientId=self.client) for link in links]
            for lower, upper in boxes:
                corners.extend(
                    [x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1]) for z in (lower[2], upper[2])
                )
        return np.asarray(corners, dtype=np.float64)

    # --- state -----------------------------------------------------------------------------------------

    def pose(self, body: int) -> np.ndarray:
        """``T_world_body (4, 4)`` of a body's base frame."""
        position, quat = pybullet.getBasePositionAndOrientation(body, physicsClientId=self.client)
        return pose_from_pos_quat(np.asarray(position), np.asarray(quat))

    def link_pose(self, body: int, link: int) -> np.ndarray:
        """``T_world_link (4, 4)`` of a link frame (URDF joint frame of the link)."""
        if link < 0:
            return self.pose(body)
        state = pybullet.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=self.client)
        return make_pose(np.asarray(state[4]), Rotation.from_quat(state[5]))

    def joint_index(self, body: int, joint_name: str) -> int:
        for joint in range(pybullet.getNumJoints(body, physicsClientId=self.client)):
            if pybullet.getJointInfo(body, joint, physicsClientId=self.client)[1].decode() == joint_name:
                return joint
        raise KeyError(f"body {body} has no joint {joint_name!r}")

    def joint_position(self, body: int, joint: int) -> float:
        return float(pybullet.getJointState(body, joint, physicsClientId=self.client)[0])

    def set_joint_position(self, body: int, joint: int, value: float) -> None:
        pybullet.resetJointState(body, joint, value, 0.0, physicsClientId=self.client)

    def set_joint_friction(self, body: int, joint: int, force: float) -> None:
        """Dry friction of a joint: a velocity motor to zero with at most ``force`` (N or N·m)."""
        pybullet.setJointMotorControl2(
            body, joint, pybullet.VELOCITY_CONTROL, targetVelocity=0.0, force=force, physicsClientId=self.client
        )

    def set_joint_spring(self, body: int, joint: int, rest: float, force: float) -> None:
        """A weak position motor that pulls a joint back to ``rest`` with at most ``force``."""
        pybullet.setJointMotorControl2(
            body,
            joint,
            pybullet.POSITION_CONTROL,
            targetPosition=rest,
            force=force,
            positionGain=0.05,
            physicsClientId=self.client,
        )

    def in_contact(self, body_a: int, body_b: int) -> bool:
        return bool(pybullet.getContactPoints(bodyA=body_a, bodyB=body_b, physicsClientId=self.client))

    def gripper_contacts(self, body: int) -> int:
        """How many fingers (0, 1 or 2) touch ``body``."""
        return sum(
            bool(
                pybullet.getContactPoints(
                    bodyA=self.robot.body, bodyB=body, linkIndexA=finger, physicsClientId=self.client
                )
            )
            for finger in self.robot.finger_links
        )

    def touches_robot(self, body: int) -> bool:
        return self.in_contact(self.robot.body, body)

    def up_axis(self, body: int) -> np.ndarray:
        """The body's z axis in the world frame ``(3,)``."""
        return self.pose(body)[:3, 2]
