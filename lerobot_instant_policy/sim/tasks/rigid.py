"""Pick-and-place tasks with free rigid objects: real friction grasps by the Panda's fingers."""

from __future__ import annotations

import numpy as np

from ..demonstrator import ScriptedWaypoint, grasp_yaw, top_down_pose
from ..scene import Part, Scene
from ..task_api import Task, register_task
from .common import BLOCK_HALF, planar_yaw, sample_positions, sample_yaw

CARRY_HEIGHT = 0.16
GRASP_DEPTH = 0.005  # EE origin (fingertip centre) this far below a block's centre


def grasp_and_move(
    scene: Scene, body: int, place_position: np.ndarray | None, lift: float = CARRY_HEIGHT
) -> list[ScriptedWaypoint]:
    """Grasp a block-like ``body`` from above; carry it to ``place_position (3,)`` (its centre) and release.

    Without ``place_position`` the object is lifted to ``lift`` and held.
    """
    pose = scene.pose(body)
    centre = pose[:3, 3]
    yaw = grasp_yaw(planar_yaw(pose), np.pi / 2)
    grasp = centre - (0.0, 0.0, GRASP_DEPTH)
    waypoints = [
        ScriptedWaypoint(top_down_pose(centre + (0.0, 0.0, 0.1), yaw), True),
        ScriptedWaypoint(top_down_pose(grasp, yaw), True),
        ScriptedWaypoint(top_down_pose(grasp, yaw), False),
        ScriptedWaypoint(top_down_pose((grasp[0], grasp[1], lift), yaw), False),
    ]
    if place_position is None:
        return waypoints
    place = np.asarray(place_position) - (0.0, 0.0, GRASP_DEPTH)
    return waypoints + [
        ScriptedWaypoint(top_down_pose((place[0], place[1], lift), yaw), False),
        ScriptedWaypoint(top_down_pose(place + (0.0, 0.0, 0.01), yaw), False),
        ScriptedWaypoint(top_down_pose(place + (0.0, 0.0, 0.01), yaw), True),
        ScriptedWaypoint(top_down_pose((place[0], place[1], lift), yaw), True),
    ]


def resting_on(scene: Scene, body: int, centre_xy: np.ndarray, radius: float, height: float) -> bool:
    """``body`` released (no finger contact), within ``radius`` of ``centre_xy`` and its centre below ``height``."""
    position = scene.pose(body)[:3, 3]
    return (
        np.linalg.norm(position[:2] - centre_xy) < radius and position[2] < height and scene.gripper_contacts(body) == 0
    )


@register_task
class PickAndLift(Task):
    """Grasp a 4 cm cube and lift it 10 cm above the table."""

    name = "pick_and_lift"
    max_episode_steps = 100

    def build(self, scene, rng):
        (xy,) = sample_positions(rng, 1, 0.0)
        self.block = scene.add_box((BLOCK_HALF,) * 3, (*xy, BLOCK_HALF), sample_yaw(rng), rgba=(0.85, 0.2, 0.2, 1))

    def is_success(self, scene):
        return scene.pose(self.block)[2, 3] > 0.1 + BLOCK_HALF

    def demonstration(self, scene):
        return grasp_and_move(scene, self.block, None, lift=0.2)


@register_task
class PickAndPlace(Task):
    """Put a cube onto a plate."""

    name = "pick_and_place"
    max_episode_steps = 150
    plate_radius = 0.07
    plate_height = 0.012

    def build(self, scene, rng):
        block_xy, plate_xy = sample_positions(rng, 2, 0.18)
        self.block = scene.add_box(
            (BLOCK_HALF,) * 3, (*block_xy, BLOCK_HALF), sample_yaw(rng), rgba=(0.2, 0.5, 0.85, 1)
        )
        self.plate = scene.add_compound(
            [Part("cylinder", (self.plate_radius, self.plate_height))],
            (*plate_xy, self.plate_height / 2),
            sample_yaw(rng),
            mass=0.0,
            rgba=(0.9, 0.9, 0.9, 1),
        )

    def is_success(self, scene):
        plate = scene.pose(self.plate)[:3, 3]
        top = plate[2] + self.plate_height / 2
        return resting_on(scene, self.block, plate[:2], self.plate_radius - 0.02, top + BLOCK_HALF + 0.01)

    def demonstration(self, scene):
        plate = scene.pose(self.plate)[:3, 3]
        target = (plate[0], plate[1], plate[2] + self.plate_height / 2 + BLOCK_HALF)
        return grasp_and_move(scene, self.block, np.asarray(target))


@register_task
class PutInTray(Task):
    """Put a cube into a walled tray."""

    name = "put_in_tray"
    max_episode_steps = 150
    inner_half = 0.07
    wall = 0.006
    wall_height = 0.035

    def build(self, scene, rng):
        block_xy, tray_xy = sample_positions(rng, 2, 0.2)
        self.block = scene.add_box((BLOCK_HALF,) * 3, (*block_xy, BLOCK_HALF), sample_yaw(rng), rgba=(0.9, 0.6, 0.1, 1))
        outer, h = self.inner_half + self.wall, self.wall_height / 2
        parts = [Part("box", (outer, outer, 0.004), (0.0, 0.0, 0.004))]
        for sign in (-1.0, 1.0):
            parts.append(Part("box", (self.wall / 2, outer, h), (sign * (outer - self.wall / 2), 0.0, h)))
            parts.append(Part("box", (outer, self.wall / 2, h), (0.0, sign * (outer - self.wall / 2), h)))
        self.tray = scene.add_compound(parts, (*tray_xy, 0.0), sample_yaw(rng), mass=0.0, rgba=(0.3, 0.6, 0.3, 1))

    def is_success(self, scene):
        tray = scene.pose(self.tray)
        local = tray[:3, :3].T @ (scene.pose(self.block)[:3, 3] - tray[:3, 3])
        inside = np.all(np.abs(local[:2]) < self.inner_half) and local[2] < self.wall_height
        return bool(inside and scene.gripper_contacts(self.block) == 0)

    def demonstration(self, scene):
        tray = scene.pose(self.tray)[:3, 3]
        return grasp_and_move(scene, self.block, np.asarray((tray[0], tray[1], 0.008 + BLOCK_HALF)))


@register_task
class StackBlocks(Task):
    """Stack a 4 cm cube on a 5 cm cube."""

    name = "stack_blocks"
    max_episode_steps = 150
    base_half = 0.025

    def build(self, scene, rng):
        top_xy, base_xy = sample_positions(rng, 2, 0.15)
        self.block = scene.add_box((BLOCK_HALF,) * 3, (*top_xy, BLOCK_HALF), sample_yaw(rng), rgba=(0.85, 0.2, 0.2, 1))
        self.base = scene.add_box(
            (self.base_half,) * 3, (*base_xy, self.base_half), sample_yaw(rng), mass=0.3, rgba=(0.2, 0.3, 0.8, 1)
        )

    def is_success(self, scene):
        base = scene.pose(self.base)[:3, 3]
        top_z = base[2] + self.base_half + BLOCK_HALF
        block_z = scene.pose(self.block)[2, 3]
        return resting_on(scene, self.block, base[:2], 0.02, top_z + 0.01) and block_z > top_z - 0.01

    def demonstration(self, scene):
        base = scene.pose(self.base)[:3, 3]
        return grasp_and_move(scene, self.block, base + (0.0, 0.0, self.base_half + BLOCK_HALF))


@register_task
class LiftLid(Task):
    """Lift the lid off a pot by its knob."""

    name = "lift_lid"
    max_episode_steps = 100
    pot_radius = 0.065
    pot_height = 0.07
    knob_half = (0.01, 0.03, 0.0125)

    def build(self, scene, rng):
        (xy,) = sample_positions(rng, 1, 0.0, x_range=(0.45, 0.6))
        self.pot = scene.add_compound(
            [Part("cylinder", (self.pot_radius, self.pot_height))],
            (*xy, self.pot_height / 2),
            0.0,
            mass=0.0,
            rgba=(0.4, 0.4, 0.45, 1),
        )
        self.lid = scene.add_compound(
            [
                Part("cylinder", (self.pot_radius + 0.005, 0.01)),
                Part("box", self.knob_half, (0.0, 0.0, 0.005 + self.knob_half[2])),
            ],
            (*xy, self.pot_height + 0.005),
            sample_yaw(rng),
            mass=0.1,
            rgba=(0.7, 0.5, 0.3, 1),
        )

    def is_success(self, scene):
        return scene.pose(self.lid)[2, 3] > self.pot_height + 0.06

    def demonstration(self, scene):
        pose = scene.pose(self.lid)
        knob = pose[:3, 3] + (0.0, 0.0, 0.005 + self.knob_half[2])
        yaw = grasp_yaw(planar_yaw(pose), np.pi)  # fingers close across the knob's thin (x) side
        grasp = knob - (0.0, 0.0, 0.004)
        return [
            ScriptedWaypoint(top_down_pose(grasp + (0.0, 0.0, 0.1), yaw), True),
            ScriptedWaypoint(top_down_pose(grasp, yaw), True),
            ScriptedWaypoint(top_down_pose(grasp, yaw), False),
            ScriptedWaypoint(top_down_pose(grasp + (0.0, 0.0, 0.15), yaw), False),
        ]
