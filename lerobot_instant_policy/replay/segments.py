"""A demonstration's actions cut into segments, each anchored to what it approaches: the structure of the anchored
replay plan (:func:`~.plan.plan_replay` with ``plan="anchored"``).

A segment ends where the demonstrator acted or changed course, read off the commanded actions ``(F, 8)`` (the
contract's layout: xyz, quaternion xyzw, gripper):

* at a gripper change: the first action with the new command (the pose where the gripper closed or opened);
* where the EE nearly stops (:class:`~..data.waypoints.StopCriterion`'s thresholds, on the commanded poses): the run's
  first action;
* where the path turns: the vertices of the Ramer-Douglas-Peucker simplification of the positions between the
  other ends, at ``turn_tolerance`` (m);
* at the last action.

Each segment's end pose is its bottleneck pose (MT3's term): it is anchored to the demonstrated object (a component
of the first cloud, :func:`~.plan.split_objects`) nearest to it. At a gripper change the nearest object is
taken however far (a grasp acts on something), and a release excludes the object grasped at the close before it
(the grasped object sits in the hand, away from where the first cloud shows it); elsewhere only an object within
``anchor_radius`` anchors the segment; a segment that approaches nothing (a lift, a carry, a retreat into free
space) is in transit between the anchored segments around it (anchor ``-1``).

While an object is held (from its close to the next gripper change), what a segment approaches is what the held
object approaches too: the grasped cloud is carried rigidly with the EE from the grasp pose, the action between the
close and the next change where the EE comes nearest to it (a gripper may be commanded shut while still descending),
``T_world_held(t) = T_world_ee(t) · T_world_ee(grasp)⁻¹``, and another object within ``anchor_radius`` of the carried
cloud anchors the segment however far the EE itself stays: a peg's tip in a hole, a puck held at a goal marker.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..contract import poses_from_vectors
from ..data.waypoints import StopCriterion, still_runs
from ..geometry.se3 import pose_distance, transform_points

WRONG_PLAN_M = 0.03  # a replay plan this far off at a gripper change or its end is wrong (plan_is_wrong)


@dataclass(frozen=True)
class SegmentConfig:
    """Where segments end and what anchors them (module docstring): ``turn_tolerance`` (m) of the path
    simplification, ``anchor_radius`` (m) within which an object anchors a segment that ends with no gripper change,
    and the ``stop`` criterion."""

    turn_tolerance: float = 0.01
    anchor_radius: float = 0.05
    stop: StopCriterion = StopCriterion()

    def __post_init__(self) -> None:
        if self.turn_tolerance <= 0 or self.anchor_radius <= 0:
            raise ValueError(f"turn_tolerance and anchor_radius must be positive, got {self.turn_tolerance}, "
                             f"{self.anchor_radius}")


@dataclass(frozen=True)
class Segments:
    """``ends (S,)``: the last action of each segment, increasing, the last one ``F − 1``; ``anchors (S,)``: the
    index of the object each segment is anchored to, into the object list it was anchored against, ``-1`` for a
    segment in transit."""

    ends: np.ndarray
    anchors: np.ndarray

    def anchored(self) -> tuple[np.ndarray, np.ndarray]:
        """The ends ``(A,)`` of the anchored segments and their anchors ``(A,)``, in order."""
        keep = self.anchors >= 0
        return self.ends[keep], self.anchors[keep]


def segment_ends(actions: np.ndarray, config: SegmentConfig = SegmentConfig()) -> np.ndarray:
    """The last action of each segment of ``actions (F, 8)`` (module docstring), ``(S,)`` int64, increasing, ending
    with ``F − 1``."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.ndim != 2 or actions.shape[1] != 8 or len(actions) < 1:
        raise ValueError(f"actions must be (F, 8) with F ≥ 1, got {actions.shape}")
    last = len(actions) - 1
    ends = acting_ends(actions, config.stop)
    fixed = sorted(ends | {0})
    for start, stop in zip(fixed[:-1], fixed[1:], strict=True):
        ends |= {start + int(vertex) for vertex in _turns(actions[start:stop + 1, :3], config.turn_tolerance)}
    if last > 0:
        ends.discard(0)
    return np.asarray(sorted(ends), dtype=np.int64)


def anchor_segments(actions: np.ndarray, objects: list[np.ndarray], config: SegmentConfig = SegmentConfig()
                    ) -> Segments | None:
    """The segments of ``actions (F, 8)`` (world frame) anchored to ``objects`` (clouds ``(P_i, 3)``, world frame, as
    the demonstration's first frame shows them), or None where no segment approaches any object."""
    if not objects:
        return None
    actions = np.asarray(actions, dtype=np.float64)
    ends = segment_ends(actions, config)
    opened = actions[:, 7] > 0.5
    T_world_ee, _ = poses_from_vectors(actions)
    anchors: list[int] = []
    grasped: int | None = None
    grasp = 0
    trees: list[cKDTree] = []  # the objects' k-d trees, built at the first grasp
    for end in ends:
        changed = end > 0 and opened[end] != opened[end - 1]
        releasing = changed and bool(opened[end])
        exclude = grasped if releasing and len(objects) > 1 else None
        nearest, distance = nearest_object(objects, actions[end, :3], exclude)
        if grasped is not None and not changed and end > grasp:
            T_moved = T_world_ee[end] @ np.linalg.inv(T_world_ee[grasp])  # the held object's motion since the grasp
            held_nearest, held_distance = _nearest_to_held(objects, trees, grasped, T_moved)
            if held_distance < distance:
                nearest, distance = held_nearest, held_distance
        anchored = changed or distance <= config.anchor_radius
        anchors.append(nearest if anchored else -1)
        if changed:
            grasped = None if releasing else nearest
            if grasped is not None:
                trees = trees or [cKDTree(points) for points in objects]
                grasp = _grasp_pose(actions[:, :3], opened, int(end), trees[grasped])
    if max(anchors) < 0:
        return None
    return Segments(ends=ends, anchors=np.asarray(anchors, dtype=np.int64))


def nearest_object(objects: list[np.ndarray], position: np.ndarray, exclude: int | None = None) -> tuple[int, float]:
    """The object (clouds ``(P_i, 3)``) with the point nearest to ``position (3,)``, other than ``exclude``, and
    that distance (m)."""
    distances = [np.inf if index == exclude else float(np.min(np.linalg.norm(points - position, axis=1)))
                 for index, points in enumerate(objects)]
    nearest = int(np.argmin(distances))
    return nearest, distances[nearest]


def _grasp_pose(positions: np.ndarray, opened: np.ndarray, close: int, grasped: cKDTree) -> int:
    """The action from ``close`` up to the next gripper change whose EE position (``positions (F, 3)``) lies
    nearest to the grasped cloud (its k-d tree): where the object starts to move with the hand."""
    change = np.flatnonzero(opened[close:] != opened[close])
    stop = close + int(change[0]) if len(change) else len(positions)
    distances, _ = grasped.query(positions[close:stop])
    return close + int(np.argmin(distances))


def _nearest_to_held(objects: list[np.ndarray], trees: list[cKDTree], grasped: int, T_moved: np.ndarray
                     ) -> tuple[int, float]:
    """The object other than ``grasped`` nearest to the grasped cloud moved by ``T_moved (4, 4)`` (world frame, its
    motion since the grasp pose), and that distance (m), read off the objects' k-d ``trees``; ``(grasped, inf)`` with
    no other object."""
    held = transform_points(T_moved, objects[grasped])
    distances = [np.inf if index == grasped else float(np.min(tree.query(held)[0])) for index, tree in enumerate(trees)]
    nearest = int(np.argmin(distances))
    return nearest, distances[nearest]


def gripper_changes(actions: np.ndarray) -> np.ndarray:
    """``(C,)`` int64: the actions of ``actions (F, 8)`` whose gripper command (thresholded at 0.5) differs from the
    one before."""
    opened = np.asarray(actions)[:, 7] > 0.5
    return np.flatnonzero(opened[1:] != opened[:-1]) + 1


def gripper_change_kinds(actions: np.ndarray) -> dict[int, tuple[str, int]]:
    """``{action index: (kind, order)}`` of the gripper changes of ``actions (F, 8)``: kind ``"close"`` or
    ``"open"``, order counting the changes of that kind before it (the k-th close of one demonstration answers the
    k-th close of another)."""
    changes, counts = {}, {"close": 0, "open": 0}
    for index in gripper_changes(actions).tolist():
        kind = "open" if actions[index, 7] > 0.5 else "close"
        changes[index] = (kind, counts[kind])
        counts[kind] += 1
    return changes


def plan_is_wrong(planned: np.ndarray, demonstrated: np.ndarray, tolerance: float = WRONG_PLAN_M) -> bool:
    """Whether the replay plan ``planned (G, 8)`` is wrong against ``demonstrated (F, 8)``, what a demonstrator did in
    the same scene (both world frame, the contract's layout): a gripper change of the demonstration that the plan
    lacks (matched by kind and order), or one, or the last action, whose commanded EE position lies further than
    ``tolerance`` (m) from the plan's. The stops and turns between do not count: two demonstrators pass them
    differently in one scene. Measured on held-out pseudo-tasks whose objects moved, a plan's worst error at a
    gripper change lies within a few millimetres or beyond 60 mm, so the count hardly depends on ``tolerance``
    between the two."""
    plan_changes = {change: step for step, change in gripper_change_kinds(planned).items()}
    for index, change in gripper_change_kinds(demonstrated).items():
        if change not in plan_changes:
            return True
        if np.linalg.norm(planned[plan_changes[change], :3] - demonstrated[index, :3]) > tolerance:
            return True
    return bool(np.linalg.norm(planned[-1, :3] - demonstrated[-1, :3]) > tolerance)


def acting_ends(actions: np.ndarray, stop: StopCriterion = SegmentConfig().stop) -> set[int]:
    """The segment ends of ``actions (F, 8)`` where the demonstrator acts: its gripper changes, the first action of
    each stop (``stop``) and its last action; :func:`segment_ends` adds the turns between them."""
    return set(gripper_changes(actions).tolist()) | set(_stop_starts(actions, stop)) | {len(actions) - 1}


def _stop_starts(actions: np.ndarray, stop: StopCriterion) -> list[int]:
    """First action of every run of at least ``stop.min_steps`` nearly still steps of the commanded poses."""
    T_world_ee, _ = poses_from_vectors(actions)
    moved, turned = pose_distance(T_world_ee[:-1], T_world_ee[1:])
    return [start for start, _ in still_runs((moved < stop.translation) & (turned < stop.rotation), stop.min_steps)]


def _turns(positions: np.ndarray, tolerance: float) -> list[int]:
    """Inner vertices (indices into ``positions (F, 3)``) of the Ramer-Douglas-Peucker simplification of the path at
    ``tolerance`` (m)."""
    if len(positions) < 3:
        return []
    start, end = positions[0], positions[-1]
    chord = end - start
    length = float(np.linalg.norm(chord))
    offsets = positions[1:-1] - start
    if length < 1e-9:
        distances = np.linalg.norm(offsets, axis=1)
    else:
        distances = np.linalg.norm(np.cross(offsets, chord / length), axis=1)
    farthest = int(np.argmax(distances)) + 1
    if distances[farthest - 1] <= tolerance:
        return []
    return (_turns(positions[:farthest + 1], tolerance) + [farthest]
            + [farthest + vertex for vertex in _turns(positions[farthest:], tolerance)])


__all__ = ["WRONG_PLAN_M", "SegmentConfig", "Segments", "acting_ends", "anchor_segments", "gripper_change_kinds",
           "gripper_changes", "nearest_object", "plan_is_wrong", "segment_ends"]
