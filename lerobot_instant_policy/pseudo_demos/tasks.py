"""Pseudo-tasks: gripper waypoints defined in the frames of two objects (paper §3.3, appendix D).

A waypoint is anchored to one object's *initial* pose, so replaying the same task in a scene with new object
poses puts every waypoint at the same place relative to its object.

Task families, a ladder from the simplest in-context problem to the paper's generator (``FAMILIES``):

- ``reach`` (the simplest): move to one pose relative to one of the two objects; no gripper change.
- ``reach_grip``: reach a pose at an object's surface, close the gripper there, retreat in a direction
  of the task's own.
- ``grasp_place``: grasp one object and place it at a pose relative to the second (pick-and-place).
- ``full`` (the paper's generator): 2–6 waypoints, at least one gripper change; ``biased_fraction`` of the tasks
  follow biased templates (grasp, pick-and-place, push, open/close by a pull or a hinge arc, press), the rest are
  random.

In every family the anchor object, the pose on it and the approach direction are drawn per task, so the motion
cannot be predicted from the scene alone: only the task's demonstrations tell it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.se3 import look_rotation, make_pose
from ..objects.library import ObjectModel

TEMPLATES = ("grasp", "pick_and_place", "push", "pull", "hinge", "press")
FAMILIES = ("reach", "reach_grip", "grasp_place", "full")
INTERPOLATIONS = ("linear", "cubic", "spherical")
GRASP_REACH = 0.03
_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass
class Waypoint:
    """Reach ``T_anchor_ee (4, 4)`` (EE pose in the anchor object's initial frame), then set the gripper.

    ``interpolation`` shapes the motion *into* this waypoint: ``control_offsets (2, 3)`` are Bézier offsets for
    ``cubic`` as fractions of the segment length, in the anchor frame; ``center (3,)`` is the arc centre for
    ``spherical``, in the anchor frame.
    """

    anchor: int
    T_anchor_ee: np.ndarray
    gripper_open: bool
    interpolation: str = "linear"
    control_offsets: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class PseudoTask:
    """One pseudo-task: two objects and the waypoints every demonstration of it reaches in order."""

    task_id: str
    template: str
    object_ids: tuple[str, str]
    waypoints: list[Waypoint]

    def gripper_changes(self) -> int:
        states = [True] + [waypoint.gripper_open for waypoint in self.waypoints]
        return sum(a != b for a, b in zip(states[:-1], states[1:], strict=True))


def sample_pseudo_task(
    task_id: str,
    objects: list[ObjectModel],
    rng: np.random.Generator,
    biased_fraction: float = 0.5,
    family: str = "full",
    waypoint_max_roll_deg: float = 180.0,
) -> PseudoTask:
    """Sample a task of ``family`` (see ``FAMILIES``) on ``objects`` (two normalised models); in the ``full`` family
    a biased template with probability ``biased_fraction``, else random waypoints. Every gripper pose the task
    draws is turned about its approach axis by a uniform angle within ±``waypoint_max_roll_deg`` (from the
    approach's reference roll, :func:`~..geometry.se3.look_rotation`); 180 is any turn, and the same draws."""
    if family not in FAMILIES:
        raise ValueError(f"unknown pseudo-task family {family!r}; known: {list(FAMILIES)}")
    if not 0.0 <= waypoint_max_roll_deg <= 180.0:
        raise ValueError(f"waypoint_max_roll_deg must lie in [0, 180] degrees, got {waypoint_max_roll_deg}")
    max_roll = float(np.deg2rad(waypoint_max_roll_deg))
    if family == "full":
        if rng.random() < biased_fraction:
            template = str(rng.choice(TEMPLATES))
            waypoints = _TEMPLATE_SAMPLERS[template](objects, rng, max_roll)
        else:
            template = "random"
            waypoints = _random_waypoints(objects, rng, max_roll)
    else:
        template = family
        waypoints = _FAMILY_SAMPLERS[family](objects, rng, max_roll)
    if not 1 <= len(waypoints) <= 6:
        raise AssertionError(f"template {template} made {len(waypoints)} waypoints")
    task = PseudoTask(task_id, template, (objects[0].object_id, objects[1].object_id), waypoints)
    if family != "reach" and task.gripper_changes() == 0:
        raise AssertionError(f"template {template} made no gripper change")
    return task


def _reach(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    """``reach``: one pose 2–10 cm off a random surface point of a random object, approached from a random direction."""
    anchor = int(rng.integers(2))
    point, normal = _surface_point(objects[anchor], rng, (-0.3, 1.0))
    position = point + normal * rng.uniform(0.02, 0.1)
    position[2] = max(position[2], 0.03)
    approach = _approach(normal, rng, rng.uniform(0.2, 1.0))
    return [Waypoint(anchor, make_pose(position, look_rotation(approach, _roll(rng, max_roll))), True, _smooth(rng))]


def _reach_grip(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    """``reach_grip``: reach a pose at a random object's surface, close the gripper, retreat 5–15 cm up and sideways."""
    anchor = int(rng.integers(2))
    grip = _grasp_pose(objects[anchor], rng, top=rng.random() < 0.6, max_roll=max_roll)
    sideways = rng.normal(size=2)
    sideways *= rng.uniform(0.0, 0.08) / np.linalg.norm(sideways)
    retreat = _offset(grip, up=rng.uniform(0.05, 0.15), shift=np.array([sideways[0], sideways[1], 0.0]))
    return [Waypoint(anchor, grip, False, _smooth(rng)), Waypoint(anchor, retreat, False)]


def _surface_point(
    model: ObjectModel, rng: np.random.Generator, normal_z: tuple[float, float] = (-1.0, 1.0)
) -> tuple[np.ndarray, np.ndarray]:
    """A surface sample ``(3,)`` and its outward normal ``(3,)`` whose z-component lies in ``normal_z``."""
    mask = (model.surface_normals[:, 2] >= normal_z[0]) & (model.surface_normals[:, 2] <= normal_z[1])
    candidates = np.flatnonzero(mask) if mask.any() else np.arange(len(model.surface_points))
    index = int(rng.choice(candidates))
    return model.surface_points[index], model.surface_normals[index]


def _approach(normal: np.ndarray, rng: np.random.Generator, down_weight: float) -> np.ndarray:
    """An approach direction between ``-normal`` and straight down, with a little noise."""
    direction = (1 - down_weight) * -normal + down_weight * _DOWN + rng.normal(scale=0.15, size=3)
    if np.linalg.norm(direction) < 1e-3:
        direction = _DOWN.copy()
    return direction / np.linalg.norm(direction)


def _grasp_pose(model: ObjectModel, rng: np.random.Generator, top: bool, max_roll: float) -> np.ndarray:
    """EE pose in the object frame that grasps a part: TCP 0–1.5 cm inside the surface, fingers across it."""
    point, normal = _surface_point(model, rng, (0.5, 1.0) if top else (-0.4, 0.4))
    approach = _approach(normal, rng, down_weight=rng.uniform(0.5, 1.0) if top else rng.uniform(0.0, 0.3))
    position = point + approach * rng.uniform(0.0, 0.015)
    return make_pose(position, look_rotation(approach, _roll(rng, max_roll)))


def _offset(pose: np.ndarray, along_approach: float = 0.0, up: float = 0.0, shift: np.ndarray | None = None) -> np.ndarray:
    """Move ``pose`` back along its approach axis (negative = retreat), up in the object frame, and by ``shift``."""
    moved = pose.copy()
    moved[:3, 3] = pose[:3, 3] + pose[:3, 2] * along_approach + np.array([0.0, 0.0, up])
    if shift is not None:
        moved[:3, 3] += shift
    return moved


def _yawed(pose: np.ndarray, yaw: float) -> np.ndarray:
    """``pose`` rotated about the object's vertical axis through its position."""
    rotated = pose.copy()
    cos, sin = np.cos(yaw), np.sin(yaw)
    rotated[:3, :3] = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]]) @ pose[:3, :3]
    return rotated


def _grasp(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    target = int(rng.integers(2))
    grasp = _grasp_pose(objects[target], rng, top=rng.random() < 0.7, max_roll=max_roll)
    waypoints = [
        Waypoint(target, _offset(grasp, along_approach=-rng.uniform(0.05, 0.12)), True, _smooth(rng)),
        Waypoint(target, grasp, False),
        Waypoint(target, _offset(grasp, up=rng.uniform(0.08, 0.2)), False),
    ]
    if rng.random() < 0.3:
        waypoints.append(Waypoint(target, grasp, True))
    return waypoints


def _pick_and_place(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    target = int(rng.integers(2))
    base = 1 - target
    grasp = _grasp_pose(objects[target], rng, top=True, max_roll=max_roll)
    lift = _offset(grasp, up=rng.uniform(0.08, 0.18))
    top_point, _ = _surface_point(objects[base], rng, (0.7, 1.0))
    place_height = objects[target].extents[2] * rng.uniform(0.5, 1.0) + rng.uniform(0.0, 0.03)
    place = _yawed(grasp, rng.uniform(-np.pi / 2, np.pi / 2))
    place[:3, 3] = top_point + np.array([0.0, 0.0, place_height])
    return [
        Waypoint(target, _offset(grasp, along_approach=-rng.uniform(0.05, 0.1)), True, _smooth(rng)),
        Waypoint(target, grasp, False),
        Waypoint(target, lift, False),
        Waypoint(base, _offset(place, up=rng.uniform(0.05, 0.1)), False, _smooth(rng), _bezier(rng)),
        Waypoint(base, place, True),
        Waypoint(base, _offset(place, up=rng.uniform(0.05, 0.12)), True),
    ]


def _push(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    target = int(rng.integers(2))
    point, normal = _surface_point(objects[target], rng, (-0.3, 0.3))
    horizontal = np.array([normal[0], normal[1], 0.0])
    horizontal /= max(np.linalg.norm(horizontal), 1e-6)
    contact_position = point + horizontal * rng.uniform(0.005, 0.02)
    approach = _approach(horizontal, rng, rng.uniform(0.6, 1.0))
    contact = make_pose(contact_position, look_rotation(approach, _roll(rng, max_roll)))
    distance = rng.uniform(0.05, 0.15)
    pushed = _offset(contact, shift=-horizontal * distance)
    return [
        Waypoint(target, _offset(contact, up=rng.uniform(0.06, 0.12), shift=horizontal * 0.04), True, _smooth(rng)),
        Waypoint(target, contact, False),
        Waypoint(target, pushed, False),
        Waypoint(target, pushed, True),
        Waypoint(target, _offset(pushed, up=rng.uniform(0.05, 0.12)), True),
    ]


def _pull(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    target = int(rng.integers(2))
    grasp = _grasp_pose(objects[target], rng, top=False, max_roll=max_roll)
    outward = -grasp[:3, 2].copy()
    outward[2] = 0.0
    outward /= max(np.linalg.norm(outward), 1e-6)
    direction = outward if rng.random() < 0.6 else -outward
    pulled = _offset(grasp, shift=direction * rng.uniform(0.05, 0.15))
    return [
        Waypoint(target, _offset(grasp, along_approach=-rng.uniform(0.05, 0.1)), True, _smooth(rng)),
        Waypoint(target, grasp, False),
        Waypoint(target, pulled, False),
        Waypoint(target, pulled, True),
        Waypoint(target, _offset(pulled, along_approach=-rng.uniform(0.04, 0.1)), True),
    ]


def _hinge(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    """Grasp a part and swing it about a hinge axis (door-like: vertical axis; lid-like: horizontal axis)."""
    target = int(rng.integers(2))
    model = objects[target]
    lid_like = rng.random() < 0.5
    grasp = _grasp_pose(model, rng, top=lid_like, max_roll=max_roll)
    half_extents = model.extents / 2
    if lid_like:
        edge_angle = rng.uniform(-np.pi, np.pi)
        axis = np.array([-np.sin(edge_angle), np.cos(edge_angle), 0.0])
        hinge_point = np.array([np.cos(edge_angle) * half_extents[0], np.sin(edge_angle) * half_extents[1], model.extents[2]])
    else:
        axis = np.array([0.0, 0.0, 1.0])
        corner = rng.choice([-1.0, 1.0], size=2) * half_extents[:2]
        hinge_point = np.array([corner[0], corner[1], 0.0])
    angle = rng.uniform(np.deg2rad(30), np.deg2rad(90)) * rng.choice([-1.0, 1.0])
    rotation = look_rotation(axis, 0.0) @ _rot_z(angle) @ look_rotation(axis, 0.0).T
    center = hinge_point + axis * ((grasp[:3, 3] - hinge_point) @ axis)
    swung = grasp.copy()
    swung[:3, :3] = rotation @ grasp[:3, :3]
    swung[:3, 3] = center + rotation @ (grasp[:3, 3] - center)
    return [
        Waypoint(target, _offset(grasp, along_approach=-rng.uniform(0.05, 0.1)), True, _smooth(rng)),
        Waypoint(target, grasp, False),
        Waypoint(target, swung, False, "spherical", center=center),
        Waypoint(target, swung, True),
        Waypoint(target, _offset(swung, along_approach=-rng.uniform(0.04, 0.1)), True),
    ]


def _press(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    target = int(rng.integers(2))
    point, normal = _surface_point(objects[target], rng, (0.7, 1.0))
    approach = _approach(normal, rng, 0.8)
    press = make_pose(point + _DOWN * rng.uniform(0.0, 0.01), look_rotation(approach, _roll(rng, max_roll)))
    above = _offset(press, up=rng.uniform(0.08, 0.15))
    return [
        Waypoint(target, above, False, _smooth(rng)),
        Waypoint(target, press, False),
        Waypoint(target, above, False),
        Waypoint(target, above, True),
    ]


def _random_waypoints(objects: list[ObjectModel], rng: np.random.Generator, max_roll: float) -> list[Waypoint]:
    """2–6 waypoints on or near random objects, random orientations and interpolations, ≥ 1 gripper change.

    After the gripper closes, later waypoints anchor to the other object (a held object moves with the gripper)
    and stay higher than the grasp, so that what is held is not pushed into the table.
    """
    count = int(rng.integers(2, 7))
    gripper = [bool(state) for state in rng.random(count) > 0.4]
    if all(gripper):
        gripper[int(rng.integers(count))] = False
    anchor = int(rng.integers(2))
    waypoints = []
    previous_open = True
    min_height = 0.01
    for index in range(count):
        point, normal = _surface_point(objects[anchor], rng, (-0.3, 1.0))
        position = point + normal * rng.uniform(-0.01, 0.08)
        position[2] = max(position[2], min_height)
        approach = _approach(normal, rng, rng.uniform(0.2, 1.0))
        pose = make_pose(position, look_rotation(approach, _roll(rng, max_roll)))
        kind = str(rng.choice(INTERPOLATIONS))
        center = objects[anchor].vertices.mean(axis=0) + rng.normal(scale=0.03, size=3)
        waypoints.append(Waypoint(anchor, pose, gripper[index], kind, _bezier(rng), center))
        if previous_open and not gripper[index]:
            anchor = 1 - anchor
            min_height = position[2] + 0.02
        previous_open = gripper[index]
    return waypoints


def _roll(rng: np.random.Generator, max_roll: float) -> float:
    """A turn about the approach axis, uniform within ±``max_roll`` (radians)."""
    return rng.uniform(-max_roll, max_roll)


def _smooth(rng: np.random.Generator) -> str:
    return "cubic" if rng.random() < 0.4 else "linear"


def _bezier(rng: np.random.Generator) -> np.ndarray:
    return rng.normal(size=(2, 3)) * rng.uniform(0.1, 0.35)


def _rot_z(angle: float) -> np.ndarray:
    cos, sin = np.cos(angle), np.sin(angle)
    return np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])


_FAMILY_SAMPLERS = {
    "reach": _reach,
    "reach_grip": _reach_grip,
    "grasp_place": _pick_and_place,
}

_TEMPLATE_SAMPLERS = {
    "grasp": _grasp,
    "pick_and_place": _pick_and_place,
    "push": _push,
    "pull": _pull,
    "hinge": _hinge,
    "press": _press,
}
