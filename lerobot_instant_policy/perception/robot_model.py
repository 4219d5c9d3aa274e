"""A robot's kinematics and link geometry from its URDF (pybullet, no physics): forward kinematics of any link
and the robot's surface posed by a joint state, to take the robot out of a scene cloud.

Joint states are given in the order of ``joint_names`` (URDF joint names). Link geometry is the URDF's collision
shapes (meshes, boxes, cylinders, spheres), sampled once in each link's frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet
import trimesh
from scipy.spatial import cKDTree

from ..geometry.se3 import pose_from_pos_quat, transform_points


class RobotModel:
    """The robot of ``urdf_path`` in a private pybullet DIRECT client.

    ``joint_names``: URDF names of the joints a state vector lists, in its order.
    ``surface_spacing``: approximate distance (m) between the surface samples of the link geometry.
    """

    def __init__(self, urdf_path: str | Path, joint_names: list[str], surface_spacing: float = 0.005):
        urdf_path = Path(urdf_path)
        if not urdf_path.is_file():
            raise FileNotFoundError(f"robot URDF {urdf_path} does not exist")
        self.client = pybullet.connect(pybullet.DIRECT)
        self.body = pybullet.loadURDF(str(urdf_path), useFixedBase=True, physicsClientId=self.client)
        self._joint_of: dict[str, int] = {}
        self._link_of: dict[str, int] = {}
        for joint in range(pybullet.getNumJoints(self.body, physicsClientId=self.client)):
            info = pybullet.getJointInfo(self.body, joint, physicsClientId=self.client)
            self._joint_of[info[1].decode()] = joint
            self._link_of[info[12].decode()] = joint
        unknown = [name for name in joint_names if name not in self._joint_of]
        if unknown:
            raise KeyError(f"URDF {urdf_path.name} has no joints {unknown}; it has {sorted(self._joint_of)}")
        self.joint_names = list(joint_names)
        self._joints = [self._joint_of[name] for name in joint_names]
        self._link_samples = self._sample_links(surface_spacing)

    def close(self) -> None:
        if pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)

    def link_pose(self, joint_positions: np.ndarray, link_name: str) -> np.ndarray:
        """``T_world_link (4, 4)`` of the URDF frame of ``link_name`` at ``joint_positions (J,)`` (robot base =
        world origin)."""
        if link_name not in self._link_of:
            raise KeyError(f"the URDF has no link {link_name!r}; it has {sorted(self._link_of)}")
        self._set_joints(joint_positions)
        state = pybullet.getLinkState(
            self.body, self._link_of[link_name], computeForwardKinematics=True, physicsClientId=self.client
        )
        return pose_from_pos_quat(np.asarray(state[4]), np.asarray(state[5]))

    def surface_points(self, joint_positions: np.ndarray) -> np.ndarray:
        """Samples ``(S, 3)`` of every link's collision surface, world frame, at ``joint_positions (J,)``."""
        self._set_joints(joint_positions)
        posed = []
        for link, samples in self._link_samples:
            if link < 0:
                position, quat = pybullet.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
            else:
                state = pybullet.getLinkState(self.body, link, computeForwardKinematics=True, physicsClientId=self.client)
                position, quat = state[0], state[1]
            posed.append(transform_points(pose_from_pos_quat(np.asarray(position), np.asarray(quat)), samples))
        return np.concatenate(posed)

    def away_from_robot(self, points: np.ndarray, joint_positions: np.ndarray, margin: float) -> np.ndarray:
        """``(P,)`` True for ``points (P, 3)`` (world) farther than ``margin`` (m) from the robot's surface."""
        if len(points) == 0:
            return np.zeros(0, dtype=bool)
        distance, _ = cKDTree(self.surface_points(joint_positions)).query(points, distance_upper_bound=margin)
        return ~np.isfinite(distance)

    def _set_joints(self, joint_positions: np.ndarray) -> None:
        joint_positions = np.asarray(joint_positions, dtype=np.float64).reshape(-1)
        if joint_positions.shape != (len(self._joints),):
            raise ValueError(
                f"joint state has {joint_positions.size} values, the robot model expects {len(self._joints)} "
                f"({self.joint_names})"
            )
        for joint, value in zip(self._joints, joint_positions, strict=True):
            pybullet.resetJointState(self.body, joint, float(value), 0.0, physicsClientId=self.client)

    def _sample_links(self, spacing: float) -> list[tuple[int, np.ndarray]]:
        """Per link with collision geometry: ``(link index, samples (S, 3) in the link's centre-of-mass frame)``."""
        rng = np.random.default_rng(0)
        links = []
        for link in range(-1, pybullet.getNumJoints(self.body, physicsClientId=self.client)):
            shapes = pybullet.getCollisionShapeData(self.body, link, physicsClientId=self.client)
            samples = [self._shape_samples(shape, spacing, rng) for shape in shapes]
            samples = [s for s in samples if len(s)]
            if samples:
                links.append((link, np.concatenate(samples)))
        return links

    @staticmethod
    def _shape_samples(shape, spacing: float, rng: np.random.Generator) -> np.ndarray:
        geometry, dimensions, filename, position, quat = shape[2], shape[3], shape[4], shape[5], shape[6]
        if geometry == pybullet.GEOM_MESH:
            mesh = trimesh.load(filename.decode() if isinstance(filename, bytes) else filename, force="mesh")
            mesh.apply_scale(np.asarray(dimensions))
        elif geometry == pybullet.GEOM_BOX:
            mesh = trimesh.creation.box(extents=np.asarray(dimensions))
        elif geometry == pybullet.GEOM_SPHERE:
            mesh = trimesh.creation.icosphere(radius=dimensions[0])
        elif geometry in (pybullet.GEOM_CYLINDER, pybullet.GEOM_CAPSULE):
            mesh = trimesh.creation.cylinder(radius=dimensions[1], height=dimensions[0])
        else:
            return np.zeros((0, 3))
        count = max(16, int(np.ceil(mesh.area / spacing**2)))
        points = np.asarray(trimesh.sample.sample_surface(mesh, count, seed=rng)[0])
        return transform_points(pose_from_pos_quat(np.asarray(position), np.asarray(quat)), points)
