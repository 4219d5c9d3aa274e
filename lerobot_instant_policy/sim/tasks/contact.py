"""Tasks solved by contact with a closed gripper: press, push, knock over."""

from __future__ import annotations

import numpy as np

from ..demonstrator import ScriptedWaypoint, grasp_yaw, top_down_pose
from ..scene import Part
from ..task_api import Task, register_task
from .common import BLOCK_HALF, planar_yaw, sample_positions, sample_yaw
from .rigid import resting_on


def push_waypoints(start: np.ndarray, end: np.ndarray, height: float, yaw: float) -> list[ScriptedWaypoint]:
    """Close the gripper above ``start (2,)``, lower to ``height``, push in a straight line to ``end (2,)``, rise."""
    return [
        ScriptedWaypoint(top_down_pose((*start, height + 0.1), yaw), False),
        ScriptedWaypoint(top_down_pose((*start, height), yaw), False),
        ScriptedWaypoint(top_down_pose((*end, height), yaw), False),
        ScriptedWaypoint(top_down_pose((*end, height + 0.1), yaw), False),
    ]


@register_task
class PushButton(Task):
    """Press a spring-loaded button down by at least 8 mm. The press is the goal, counted at the first step the
    button is down (a button does not stay pressed)."""

    name = "push_button"
    max_episode_steps = 80
    success_hold_steps = 1
    cap_top = 0.05

    def build(self, scene, rng):
        (xy,) = sample_positions(rng, 1, 0.0)
        self.button = scene.load_urdf("button.urdf", (*xy, 0.0), sample_yaw(rng))
        self.press = scene.joint_index(self.button, "press")
        scene.set_joint_spring(self.button, self.press, rest=0.0, force=4.0)

    def is_success(self, scene):
        return scene.joint_position(self.button, self.press) < -0.008

    def demonstration(self, scene):
        pose = scene.pose(self.button)
        centre, yaw = pose[:3, 3], grasp_yaw(planar_yaw(pose), np.pi / 2)
        return [
            ScriptedWaypoint(top_down_pose(centre + (0.0, 0.0, 0.12), yaw), False),
            ScriptedWaypoint(top_down_pose(centre + (0.0, 0.0, self.cap_top - 0.016), yaw), False),
            ScriptedWaypoint(top_down_pose(centre + (0.0, 0.0, 0.12), yaw), False),
        ]


RESTING_TOLERANCE = 0.01  # a cube resting on the table has its centre at BLOCK_HALF; below BLOCK_HALF + this


@register_task
class SlideBlock(Task):
    """Push a cube onto a flat 10 cm target square (seen, not felt): it must rest on the table, released (no finger
    touching it), its centre within 5 cm of the square's in the plane, so a cube carried in the gripper above the
    square does not count."""

    name = "slide_block"
    max_episode_steps = 120
    target_half = 0.05

    def build(self, scene, rng):
        # The target lies along one of the block's face normals, so a flat push does not turn the block.
        for _ in range(100):
            (block_xy,) = sample_positions(rng, 1, 0.0, x_range=(0.45, 0.6), y_range=(-0.15, 0.15))
            block_yaw = sample_yaw(rng)
            heading = block_yaw + np.pi / 2 * rng.integers(4)
            target_xy = block_xy + rng.uniform(0.12, 0.18) * np.array([np.cos(heading), np.sin(heading)])
            if 0.38 <= target_xy[0] <= 0.68 and abs(target_xy[1]) <= 0.22:
                break
        self.block = scene.add_box((BLOCK_HALF,) * 3, (*block_xy, BLOCK_HALF), block_yaw, rgba=(0.9, 0.5, 0.1, 1))
        self.target = scene.add_compound(
            [Part("box", (self.target_half, self.target_half, 0.001))],
            (*target_xy, 0.001),
            sample_yaw(rng),
            mass=0.0,
            rgba=(0.2, 0.8, 0.3, 1),
            collision=False,
        )

    def is_success(self, scene):
        return bool(resting_on(scene, self.block, scene.pose(self.target)[:2, 3], self.target_half,
                               BLOCK_HALF + RESTING_TOLERANCE))

    def demonstration(self, scene):
        block, target = scene.pose(self.block)[:2, 3], scene.pose(self.target)[:2, 3]
        direction = (target - block) / np.linalg.norm(target - block)
        yaw = grasp_yaw(np.arctan2(direction[1], direction[0]) + np.pi / 2, np.pi)  # fingers side by side
        contact = BLOCK_HALF + 0.012
        return push_waypoints(block - (contact + 0.03) * direction, target - contact * direction, 0.012, yaw)


@register_task
class KnockOver(Task):
    """Topple a standing tall block (tilt beyond 60°)."""

    name = "knock_over"
    max_episode_steps = 100
    half = (0.015, 0.015, 0.07)

    def build(self, scene, rng):
        (xy,) = sample_positions(rng, 1, 0.0, x_range=(0.45, 0.6))
        self.pillar = scene.add_box(self.half, (*xy, self.half[2]), sample_yaw(rng), mass=0.15, rgba=(0.6, 0.2, 0.7, 1))

    def is_success(self, scene):
        return bool(scene.up_axis(self.pillar)[2] < 0.5)

    def demonstration(self, scene):
        pose = scene.pose(self.pillar)
        heading = planar_yaw(pose)
        direction = np.array([np.cos(heading), np.sin(heading)])
        centre = pose[:2, 3]
        yaw = grasp_yaw(heading + np.pi / 2, np.pi)
        return push_waypoints(centre - 0.06 * direction, centre + 0.08 * direction, 2 * self.half[2] - 0.03, yaw)
