"""Tasks with articulated objects built from URDFs in ``assets/sim``: a drawer and a box with a hinged lid."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ...geometry.se3 import make_pose
from ..demonstrator import ScriptedWaypoint, grasp_yaw, top_down_pose
from ..scene import Scene
from ..task_api import Task, register_task
from .common import planar_yaw, sample_positions, sample_yaw

DRAWER_FRICTION = 2.0  # N
LID_FRICTION = 0.5  # N·m, holds the lid wherever it is left
HANDLE_OFFSET_DRAWER = np.array([-0.18, 0.0, 0.075])  # handle bar centre in the drawer link frame (joint 0)
HANDLE_OFFSET_LID = np.array([0.14, 0.0, 0.0375])  # handle bar centre in the lid link frame
GRASP_DEPTH = 0.005


class _DrawerTask(Task):
    max_episode_steps = 120

    def _build_drawer(self, scene: Scene, rng: np.random.Generator, opening: float) -> None:
        (xy,) = sample_positions(rng, 1, 0.0, x_range=(0.62, 0.7), y_range=(-0.12, 0.12))
        self.drawer = scene.load_urdf("drawer.urdf", (*xy, 0.0), sample_yaw(rng))
        self.joint = scene.joint_index(self.drawer, "drawer")
        scene.set_joint_position(self.drawer, self.joint, opening)
        scene.set_joint_friction(self.drawer, self.joint, DRAWER_FRICTION)

    def _handle_at(self, scene: Scene, opening: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Handle centre ``(3,)`` at drawer ``opening``, the pull direction ``(3,)`` and the grasp yaw."""
        pose = scene.pose(self.drawer)
        pull = -pose[:3, 0]
        handle = pose[:3, :3] @ HANDLE_OFFSET_DRAWER + pose[:3, 3] + opening * pull
        return handle, pull, grasp_yaw(planar_yaw(pose), np.pi)

    def opening(self, scene: Scene) -> float:
        return scene.joint_position(self.drawer, self.joint)


@register_task
class OpenDrawer(_DrawerTask):
    """Pull a closed drawer out by at least 10 cm."""

    name = "open_drawer"

    def build(self, scene, rng):
        self._build_drawer(scene, rng, 0.0)

    def is_success(self, scene):
        return self.opening(scene) > 0.1

    def demonstration(self, scene):
        handle, pull, yaw = self._handle_at(scene, self.opening(scene))
        grasp = handle - (0.0, 0.0, GRASP_DEPTH)
        return [
            ScriptedWaypoint(top_down_pose(grasp + (0.0, 0.0, 0.1), yaw), True),
            ScriptedWaypoint(top_down_pose(grasp, yaw), True),
            ScriptedWaypoint(top_down_pose(grasp, yaw), False),
            ScriptedWaypoint(top_down_pose(grasp + 0.15 * pull, yaw), False),
            ScriptedWaypoint(top_down_pose(grasp + 0.15 * pull, yaw), True),
        ]


@register_task
class CloseDrawer(_DrawerTask):
    """Push an open drawer shut (within 2 cm)."""

    name = "close_drawer"

    def build(self, scene, rng):
        self._build_drawer(scene, rng, float(rng.uniform(0.12, 0.18)))

    def is_success(self, scene):
        return self.opening(scene) < 0.02

    def demonstration(self, scene):
        handle, pull, yaw = self._handle_at(scene, self.opening(scene))
        start = handle + 0.035 * pull - (0.0, 0.0, 0.01)
        end = handle - self.opening(scene) * pull + 0.02 * pull - (0.0, 0.0, 0.01)
        return [
            ScriptedWaypoint(top_down_pose(start + (0.0, 0.0, 0.1), yaw), False),
            ScriptedWaypoint(top_down_pose(start, yaw), False),
            ScriptedWaypoint(top_down_pose(end, yaw), False),
            ScriptedWaypoint(top_down_pose(end + (0.0, 0.0, 0.1), yaw), False),
        ]


class _BoxTask(Task):
    max_episode_steps = 150

    def _build_box(self, scene: Scene, rng: np.random.Generator, angle: float) -> None:
        (xy,) = sample_positions(rng, 1, 0.0, x_range=(0.45, 0.58), y_range=(-0.15, 0.15))
        self.box = scene.load_urdf("box.urdf", (*xy, 0.0), sample_yaw(rng))
        self.joint = scene.joint_index(self.box, "lid")
        scene.set_joint_position(self.box, self.joint, angle)
        scene.set_joint_friction(self.box, self.joint, LID_FRICTION)

    def angle(self, scene: Scene) -> float:
        return scene.joint_position(self.box, self.joint)

    def _rotate_about_hinge(self, scene: Scene, T_world_ee: np.ndarray, angle: float) -> np.ndarray:
        """``T_world_ee`` carried along by opening the lid further by ``angle`` (rad)."""
        pose = scene.pose(self.box)
        hinge = pose[:3, :3] @ np.array([-0.08, 0.0, 0.08]) + pose[:3, 3]
        rotation = Rotation.from_rotvec(-pose[:3, 1] * angle).as_matrix()
        return make_pose(hinge + rotation @ (T_world_ee[:3, 3] - hinge), rotation @ T_world_ee[:3, :3])

    def _lid_frame(self, scene: Scene) -> np.ndarray:
        return scene.link_pose(self.box, self.joint)


@register_task
class OpenBox(_BoxTask):
    """Open a box's hinged lid beyond 52° by its handle."""

    name = "open_box"

    def build(self, scene, rng):
        self._build_box(scene, rng, 0.0)

    def is_success(self, scene):
        return self.angle(scene) > 0.9

    def demonstration(self, scene):
        lid = self._lid_frame(scene)
        handle = lid[:3, :3] @ HANDLE_OFFSET_LID + lid[:3, 3]
        yaw = grasp_yaw(planar_yaw(lid), np.pi)
        grasp = top_down_pose(handle - (0.0, 0.0, GRASP_DEPTH), yaw)
        above = top_down_pose(handle + (0.0, 0.0, 0.1), yaw)
        arc = [ScriptedWaypoint(self._rotate_about_hinge(scene, grasp, angle), False) for angle in np.linspace(0.2, 1.1, 5)]
        return [ScriptedWaypoint(above, True), ScriptedWaypoint(grasp, True), ScriptedWaypoint(grasp, False), *arc]


@register_task
class CloseBox(_BoxTask):
    """Push an open lid shut (below 5°) with the closed gripper."""

    name = "close_box"

    def build(self, scene, rng):
        self._build_box(scene, rng, float(rng.uniform(1.15, 1.35)))

    def is_success(self, scene):
        return self.angle(scene) < 0.08

    def demonstration(self, scene):
        angle = self.angle(scene)
        lid = self._lid_frame(scene)
        # Where the fingertips touch the lid's top surface, 10 cm from the hinge, expressed as if closed.
        closed_contact = self._rotate_about_hinge(
            scene, top_down_pose(lid[:3, :3] @ np.array([0.1, 0.0, 0.022]) + lid[:3, 3], 0.0), -angle
        )
        closed_contact = top_down_pose(closed_contact[:3, 3], grasp_yaw(planar_yaw(lid), np.pi))
        start = self._rotate_about_hinge(scene, closed_contact, angle + 0.05)
        back_off = start.copy()
        back_off[:3, 3] -= 0.08 * start[:3, 2]
        arc = [
            ScriptedWaypoint(self._rotate_about_hinge(scene, closed_contact, a), False) for a in np.linspace(angle, -0.04, 7)
        ]
        return [ScriptedWaypoint(back_off, False), ScriptedWaypoint(start, False), *arc]
