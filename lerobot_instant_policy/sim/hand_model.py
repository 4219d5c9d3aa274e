"""An articulated human hand in pybullet, posed as a parallel gripper: a palm and five three-segment fingers whose
joints put the thumb and index tips where a gripper's fingertips would be, and its 21 landmarks in MediaPipe's layout.

The hand is built procedurally (``pybullet.createMultiBody``): the base is the palm, a convex slab through the
palm's landmarks (wrist, thumb CMC, the four finger MCPs); each finger is a chain of three capsule segments on
revolute joints about one flexion axis (a planar finger). Every coordinate is given in the EE frame of the gripper
the hand stands in for (``sim.robot``: z the approach direction, y the opening axis), and the base frame *is* that
EE frame, so posing the hand for a gripper pose ``T_world_ee`` and an aperture is: put the base at ``T_world_ee``,
then solve the thumb's and the index's joints so that their tips lie at ``(0, -aperture/2, 0)`` and
``(0, +aperture/2, 0)`` (planar two-link inverse kinematics, the last joint's bend fixed), and curl the middle, ring
and little fingers the more the pinch closes. The palm point of ``perception.hand`` (the mean of the wrist and the
index and middle MCPs) lies on the EE z axis behind the tips, so ``perception.hand.map_hand_to_gripper`` reads this
hand back as exactly ``T_world_ee``.

Landmarks (:meth:`SimulatedHand.landmarks`) are read from pybullet's link frames: a finger's MCP (thumb: CMC),
PIP and DIP (thumb: MCP, IP) are its joints' origins, its tip the end of its last segment's axis; the tip landmark
thus lies inside the fingertip, a capsule radius from its surface, as MediaPipe's does.

All masses are zero: the hand is a kinematic body (set, not simulated), an immovable obstacle to the objects it
touches. Only the thumb, the index and the palm collide; the middle, ring and little fingers are seen by the
cameras but pass through objects, since they carry nothing in a pinch and would otherwise shove objects they merely
brush against while curling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from ..geometry.se3 import pose_to_pos_quat

NUM_FINGERS = 5
THUMB, INDEX = 0, 1
SEGMENTS = 3
WRIST_EE = np.array([0.0, 0.02, -0.14])
SKIN_RGBA = (0.87, 0.68, 0.56, 1.0)
PALM_HALF_THICKNESS = 0.008


@dataclass(frozen=True)
class Finger:
    """One finger in the EE frame: its base joint ``base (3,)`` (thumb CMC, else MCP), its flexion ``axis (3,)``,
    ``lengths`` of its three segments (m), capsule ``radius`` (m) and the fixed bend ``last_bend`` (rad) of its last
    joint while it is solved for a tip position."""

    base: tuple[float, float, float]
    axis: tuple[float, float, float]
    lengths: tuple[float, float, float]
    radius: float
    last_bend: float = 0.0

    def frame(self) -> np.ndarray:
        """``R_ee_finger (3, 3)``: columns the flexion axis x, y = z × x, and z, the straight finger's direction
        (the EE z axis made orthogonal to the axis). Flexion by a positive angle turns z towards -y."""
        x = np.asarray(self.axis, dtype=np.float64) / np.linalg.norm(self.axis)
        z = np.array([0.0, 0.0, 1.0]) - x[2] * x
        z /= np.linalg.norm(z)
        return np.stack([x, np.cross(z, x), z], axis=1)


def _pinch_axis(base: tuple[float, float, float]) -> tuple[float, float, float]:
    """The flexion axis of a finger at ``base`` whose plane holds the EE y axis (where the pinching tip goes)."""
    axis = np.cross([0.0, 1.0, 0.0], -np.asarray(base))
    return tuple(axis / np.linalg.norm(axis))


_INDEX_MCP = (-0.01, 0.035, -0.065)
_THUMB_CMC = (0.0, -0.012, -0.1)
FINGERS = (
    Finger(_THUMB_CMC, (-1.0, 0.0, 0.0), (0.05, 0.04, 0.032), 0.009, 0.15),
    Finger(_INDEX_MCP, _pinch_axis(_INDEX_MCP), (0.04, 0.025, 0.02), 0.008, 0.3),
    Finger((0.01, 0.04, -0.068), (1.0, 0.0, 0.0), (0.045, 0.028, 0.022), 0.008),
    Finger((0.028, 0.038, -0.074), (1.0, 0.0, 0.0), (0.042, 0.026, 0.02), 0.0075),
    Finger((0.044, 0.033, -0.083), (1.0, 0.0, 0.0), (0.033, 0.02, 0.018), 0.007),
)
# the curl of the middle, ring and little fingers per joint (rad): CURL_OPEN at MAX_APERTURE, + CURL_CLOSING closed
CURL_OPEN, CURL_CLOSING, CURL_SHARE = 0.35, 0.8, (1.0, 1.1, 0.7)
MIN_APERTURE = FINGERS[THUMB].radius + FINGERS[INDEX].radius + 0.001  # the tips all but touching
MAX_APERTURE = 0.12


def solve_pinch_finger(finger: Finger, tip_ee: np.ndarray) -> np.ndarray:
    """The three joint angles ``(3,)`` (rad) that put ``finger``'s tip at ``tip_ee (3,)`` (EE frame, in the finger's
    plane), flexed towards the palm side (two-link inverse kinematics with the last bend fixed; out of reach: as
    close as the finger gets)."""
    local = finger.frame().T @ (np.asarray(tip_ee) - np.asarray(finger.base))
    target = complex(local[2], -local[1])  # the finger's plane as complex numbers: z + i(-y), flexion = arg
    first, second, third = finger.lengths
    distal = second + third * np.exp(1j * finger.last_bend)
    reach, offset = abs(distal), np.angle(distal)
    distance = abs(target)
    cosine = (distance ** 2 - first ** 2 - reach ** 2) / (2 * first * reach)
    bend = float(np.arccos(np.clip(cosine, -1.0, 1.0)))
    base = np.angle(target) - np.arctan2(reach * np.sin(bend), first + reach * np.cos(bend))
    return np.array([base, bend - offset, finger.last_bend])


def curl_angles(aperture: float) -> np.ndarray:
    """``(3,)`` joint angles (rad) of the middle, ring and little fingers at ``aperture`` (m)."""
    closing = 1.0 - np.clip((aperture - MIN_APERTURE) / (MAX_APERTURE - MIN_APERTURE), 0.0, 1.0)
    return (CURL_OPEN + CURL_CLOSING * closing) * np.asarray(CURL_SHARE)


class SimulatedHand:
    """The hand of the module docstring in pybullet client ``client``; :meth:`set_pose` places it.

    ``body``: its pybullet body id (its segmentation id in camera images); ``pinch_links``: the link indices of the
    thumb's and the index's last segments.
    """

    def __init__(self, client: int):
        self.client = client
        palm_points = np.stack([WRIST_EE, *[finger.base for finger in FINGERS]])
        centre = palm_points.mean(axis=0)
        normal = np.linalg.svd(palm_points - centre)[2][-1]
        slab = np.concatenate([palm_points + PALM_HALF_THICKNESS * normal, palm_points - PALM_HALF_THICKNESS * normal])
        faces = ConvexHull(slab).simplices
        palm_collision = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=slab.tolist(),
                                                       physicsClientId=client)
        palm_visual = pybullet.createVisualShape(pybullet.GEOM_MESH, vertices=slab.tolist(),
                                                 indices=faces.reshape(-1).tolist(), rgbaColor=SKIN_RGBA,
                                                 physicsClientId=client)
        link = dict(masses=[], collisions=[], visuals=[], positions=[], orientations=[], parents=[])
        for index, finger in enumerate(FINGERS):
            quat = Rotation.from_matrix(finger.frame()).as_quat()
            for segment, length in enumerate(finger.lengths):
                link["collisions"].append(pybullet.createCollisionShape(
                    pybullet.GEOM_CAPSULE, radius=finger.radius, height=length,
                    collisionFramePosition=(0.0, 0.0, length / 2), physicsClientId=client))
                link["visuals"].append(pybullet.createVisualShape(
                    pybullet.GEOM_CAPSULE, radius=finger.radius, length=length, rgbaColor=SKIN_RGBA,
                    visualFramePosition=(0.0, 0.0, length / 2), physicsClientId=client))
                first = segment == 0
                link["positions"].append(finger.base if first else (0.0, 0.0, finger.lengths[segment - 1]))
                link["orientations"].append(quat.tolist() if first else (0.0, 0.0, 0.0, 1.0))
                link["parents"].append(0 if first else SEGMENTS * index + segment)  # 0: the palm, k: link k - 1
        count = len(link["parents"])
        self.body = pybullet.createMultiBody(
            baseMass=0.0, baseCollisionShapeIndex=palm_collision, baseVisualShapeIndex=palm_visual,
            basePosition=(0.0, 0.0, -10.0), linkMasses=[0.0] * count, linkCollisionShapeIndices=link["collisions"],
            linkVisualShapeIndices=link["visuals"], linkPositions=link["positions"],
            linkOrientations=link["orientations"], linkInertialFramePositions=[(0.0, 0.0, 0.0)] * count,
            linkInertialFrameOrientations=[(0.0, 0.0, 0.0, 1.0)] * count, linkParentIndices=link["parents"],
            linkJointTypes=[pybullet.JOINT_REVOLUTE] * count, linkJointAxis=[(1.0, 0.0, 0.0)] * count,
            physicsClientId=client,
        )
        for index in range(2, NUM_FINGERS):  # the curling fingers collide with nothing
            for segment in range(SEGMENTS):
                pybullet.setCollisionFilterGroupMask(self.body, SEGMENTS * index + segment, 0, 0,
                                                     physicsClientId=client)
        self.pinch_links = (SEGMENTS * THUMB + SEGMENTS - 1, SEGMENTS * INDEX + SEGMENTS - 1)
        self.aperture = MAX_APERTURE

    def set_pose(self, T_world_ee: np.ndarray, aperture: float) -> None:
        """Place the palm at ``T_world_ee (4, 4)`` and the thumb and index tips ``aperture`` m apart on its y axis
        (clipped to ``[MIN_APERTURE, MAX_APERTURE]``), the other fingers curled to match (kinematic: no dynamics)."""
        self.aperture = float(np.clip(aperture, MIN_APERTURE, MAX_APERTURE))
        position, quat = pose_to_pos_quat(T_world_ee)
        pybullet.resetBasePositionAndOrientation(self.body, position.tolist(), quat.tolist(),
                                                 physicsClientId=self.client)
        half = self.aperture / 2
        angles = [solve_pinch_finger(FINGERS[THUMB], np.array([0.0, -half, 0.0])),
                  solve_pinch_finger(FINGERS[INDEX], np.array([0.0, half, 0.0]))]
        angles += [curl_angles(self.aperture)] * (NUM_FINGERS - 2)
        for index, finger_angles in enumerate(angles):
            for segment, angle in enumerate(finger_angles):
                pybullet.resetJointState(self.body, SEGMENTS * index + segment, float(angle), 0.0,
                                         physicsClientId=self.client)

    def landmarks(self) -> np.ndarray:
        """``landmarks_world (21, 3)``: the hand's landmarks in MediaPipe's layout (module docstring)."""
        base_position, base_quat = pybullet.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        base_rotation = np.asarray(pybullet.getMatrixFromQuaternion(base_quat)).reshape(3, 3)
        landmarks = [np.asarray(base_position) + base_rotation @ WRIST_EE]
        for index, finger in enumerate(FINGERS):
            states = pybullet.getLinkStates(self.body, list(range(SEGMENTS * index, SEGMENTS * (index + 1))),
                                            computeForwardKinematics=True, physicsClientId=self.client)
            landmarks += [np.asarray(state[4]) for state in states]
            last = np.asarray(pybullet.getMatrixFromQuaternion(states[-1][5])).reshape(3, 3)
            landmarks.append(np.asarray(states[-1][4]) + last[:, 2] * finger.lengths[-1])
        return np.stack(landmarks)
