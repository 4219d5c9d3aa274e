"""A demonstration replayed in the live scene: the plan of the ``demo_replay`` baseline, and the guess that
``instant_policy`` can start its denoising from (``InstantPolicyConfig.replay_init_strength``).

:func:`plan_replay` registers the first-frame cloud of every demonstration of a task onto the live cloud
(:func:`~..geometry.registration.register_rigid`: principal axes + trimmed ICP), keeps the demonstration that fits
best (lowest ``fit_error``) and moves its actions by the estimated ``T_now_demo``:
``T_world_ee_now = T_now_demo @ T_world_ee_demo`` for every commanded pose, gripper commands unchanged.

Per object (``per_object=True``), for tasks whose two objects move independently between demonstrations: each
cloud is split into objects (:func:`split_objects`), each demonstrated object is registered onto the live object it
fits best, and the actions follow the object they act on. The grasped object ``A`` is the one nearest the gripper
when it first closes (action ``c``), the reference ``B`` the other object nearest the gripper when it opens again
(action ``r``). Actions up to ``c`` move with ``A`` (``T_A``), from ``r`` on with ``B`` (``T_B``); in the carry
between them each pose moved with ``A`` is blended into the same pose moved with ``B`` (position linearly, rotation by
slerp) by the fraction of the carry's path the demonstrated gripper has travelled. A demonstration without that
structure (one object, no grasp and release) is planned whole.

Anchored (``plan="anchored"``), for every demonstration: its actions are cut into segments at gripper changes, stops and
turns, each anchored to the demonstrated object its end pose, or the object the gripper holds, approaches
(:mod:`.segments`); each anchor is registered onto the live object it fits best (one-to-one), and an anchored segment's
end moves with its anchor. Between two anchored ends the poses are blended from the first anchor's motion into the
second's by the fraction of the path between them travelled, as in the per-object carry, so the joins are smooth and a
segment in transit (a lift, a carry) drifts from what it left to what it approaches; before the first anchored end the
poses move with the first anchor, after the last with the last. A grasp and place is anchored as the per-object plan
plans it; a push, a reach to a marker, a handle and one object take the same path. A demonstration whose segments
approach no object is planned whole.

By consensus (``plan="consensus"``), for tasks with two or more demonstrations: every demonstration is planned
anchored, per object and whole, and the plan whose demonstrations agree best in the live scene
(:func:`~.agreement.plans_disagreement`) is executed: another plan replaces the anchored one only where its
demonstrations part by :data:`CONSENSUS_MARGIN_M` less (two right plans' disagreements differ by millimetres). Each
plan goes wrong in its own way (anchored: a symmetric object's quarter turn, registered on its own without the
layout that told the demonstrator which face to push; whole: objects that moved apart between demonstrations), and a
wrong plan's demonstrations part where right ones coincide. With one demonstration there is nothing to compare:
anchored.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..contract import poses_from_vectors, vectors_from_poses
from ..data.demonstrations import Demonstration
from ..geometry.registration import RegistrationConfig, RegistrationResult, register_rigid
from .agreement import plans_disagreement
from .segments import SegmentConfig, anchor_segments, nearest_object

# The registration of the replay an instant_policy denoises from (``replay_init_strength``) and trains to refine:
# yaw-only, tabletop objects standing upright (the demo_replay baseline's default too).
REPLAY_REGISTRATION = RegistrationConfig(yaw_only=True)
# The plans plan_replay makes: one motion for the whole cloud, per object for a grasp and release, per segment, or
# the one of those three the demonstrations agree on.
REPLAY_PLANS = ("whole", "per_object", "anchored", "consensus")
# The plans a consensus weighs, in the order that wins a tie, and by how much less (m) a later plan's demonstrations
# must part to replace an earlier one (chosen on the dev seeds' demonstration sets, journal 2026-12-06).
CONSENSUS_PLANS = ("anchored", "per_object", "whole")
CONSENSUS_MARGIN_M = 0.01


def replay_plan_name(per_object: bool, anchored: bool, consensus: bool = False) -> str:
    """The plan a config's three switches name (they exclude each other; none: whole)."""
    if per_object + anchored + consensus > 1:
        raise ValueError("a replay is planned per object, anchored per segment or by consensus: one of them, not two")
    return "consensus" if consensus else "anchored" if anchored else "per_object" if per_object else "whole"


@dataclass(frozen=True)
class ReplaySource:
    """What a replay reads of one demonstration: its first cloud ``first_cloud (P, 3)`` (world frame) and its
    actions ``action (F, 8)``."""

    first_cloud: np.ndarray
    action: np.ndarray

    @classmethod
    def of(cls, demonstration: Demonstration) -> ReplaySource:
        return cls(demonstration.points_world[0], demonstration.action)


@dataclass(frozen=True)
class ReplayPlan:
    """The actions one env executes: ``actions (F, 8)`` in the world frame, from demonstration ``demo_index`` of
    ``task`` moved by ``T_now_demo (4, 4)`` (whole-cloud plan) or by ``T_now_demo_per_action (F, 4, 4)`` (per-object
    plan); ``registration`` is the winning whole-cloud fit, or in a per-object plan the grasped object's fit (then
    ``T_now_demo`` is its motion, ``T_A``), and ``object_fits`` the per-object fits (``A``, ``B``). A per-object plan
    registers no whole cloud."""

    task: str
    demo_index: int
    T_now_demo: np.ndarray
    actions: np.ndarray
    registration: RegistrationResult
    T_now_demo_per_action: np.ndarray | None = None
    object_fits: tuple[RegistrationResult, ...] = ()

    @property
    def fit_error(self) -> float:
        """How well the plan's registration fits (m): the mean ``fit_error`` of its object fits, or of the
        whole-cloud fit where it has none."""
        fits = self.object_fits or (self.registration,)
        return float(np.mean([fit.fit_error for fit in fits]))


def plan_replay(
    task: str,
    demonstrations: Sequence[Demonstration | ReplaySource],
    cloud_now: np.ndarray,
    config: RegistrationConfig,
    plan: str = "whole",
) -> ReplayPlan:
    """Register every demonstration of ``task`` onto ``cloud_now (P, 3)`` (world frame) and plan the best one's
    actions in the live scene: ``plan`` one of :data:`REPLAY_PLANS` (module docstring); a demonstration that the
    per-object or anchored plan cannot structure is planned whole. A demonstration is read through its
    :class:`ReplaySource` (its first cloud and its actions)."""
    return best_plan(plan_each(task, demonstrations, cloud_now, config, plan))


def plan_each(
    task: str,
    demonstrations: Sequence[Demonstration | ReplaySource],
    cloud_now: np.ndarray,
    config: RegistrationConfig,
    plan: str = "whole",
) -> list[ReplayPlan]:
    """Every demonstration's own plan in the live scene, in their order (:func:`plan_replay`'s candidates): structured
    as ``plan`` asks where the demonstration allows, else whole; by consensus, the plans of the one of
    :data:`CONSENSUS_PLANS` whose demonstrations agree best (module docstring)."""
    if plan not in REPLAY_PLANS:
        raise ValueError(f"unknown replay plan {plan!r}: expected one of {REPLAY_PLANS}")
    if not demonstrations:
        raise ValueError(f"no demonstrations of task {task!r} to replay")
    demonstrations = [demo if isinstance(demo, ReplaySource) else ReplaySource.of(demo) for demo in demonstrations]
    families = (plan,) if plan != "consensus" else CONSENSUS_PLANS if len(demonstrations) > 1 else CONSENSUS_PLANS[:1]
    live_objects = split_objects(cloud_now) if any(family in _STRUCTURED for family in families) else []
    whole: dict[int, ReplayPlan] = {}  # a demonstration's whole-cloud plan, registered once for every family
    chosen, least = [], np.inf
    for family in families:
        planner = _STRUCTURED.get(family)
        plans = []
        for index, demo in enumerate(demonstrations):
            structured = planner(task, index, demo, live_objects, config) if planner else None
            if structured is None and index not in whole:
                whole[index] = _plan_whole(task, index, demo, cloud_now, config)
            plans.append(whole[index] if structured is None else structured)
        if len(families) == 1:
            return plans
        disagreement = plans_disagreement([candidate.actions for candidate in plans])
        if disagreement < least - CONSENSUS_MARGIN_M:  # least is inf until a family is chosen
            chosen, least = plans, disagreement
    return chosen


def best_plan(plans: Sequence[ReplayPlan]) -> ReplayPlan:
    """The plan :func:`plan_replay` executes among one task's :func:`plan_each`: the structured plan (per object or
    anchored) that fits best where there is one, else the whole-cloud plan that fits best
    (:attr:`ReplayPlan.fit_error`)."""
    structured = [candidate for candidate in plans if candidate.object_fits]
    return min(structured or plans, key=lambda candidate: candidate.fit_error)


def split_objects(points: np.ndarray, gap: float = 0.02, min_fraction: float = 0.02) -> list[np.ndarray]:
    """The objects of a segmented cloud ``points (P, 3)``: connected components of the graph joining points closer
    than ``gap`` (m), largest first, without components of fewer than ``min_fraction · P`` points (stray points)."""
    pairs = cKDTree(points).query_pairs(gap, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    _, labels = connected_components(graph, directed=False)
    sizes = np.bincount(labels)
    kept = [label for label in np.argsort(-sizes, kind="stable") if sizes[label] >= min_fraction * len(points)]
    return [points[labels == label] for label in kept]


def _plan_per_object(
    task: str,
    demo_index: int,
    demo: ReplaySource,
    live_objects: list[np.ndarray],
    config: RegistrationConfig,
) -> ReplayPlan | None:
    """The per-object plan of one demonstration (module docstring), or None where it has no grasp-and-release
    between two objects or the live cloud has fewer than two objects."""
    demo_objects = split_objects(demo.first_cloud)
    opened = demo.action[:, 7] > 0.5
    closes = np.flatnonzero(opened[:-1] & ~opened[1:]) + 1
    if len(demo_objects) < 2 or len(live_objects) < 2 or not len(closes):
        return None
    close = int(closes[0])
    reopens = np.flatnonzero(opened[close:]) + close
    if not len(reopens):
        return None
    release = int(reopens[0])
    positions = demo.action[:, :3]
    grasped, _ = nearest_object(demo_objects, positions[close])
    reference, _ = nearest_object(demo_objects, positions[release], exclude=grasped)
    fits = _match_objects([demo_objects[grasped], demo_objects[reference]], live_objects, config)
    T_A, T_B = (fit.T_target_source for fit in fits)
    T_world_ee, gripper_open = poses_from_vectors(demo.action)
    T_world_planned = _blend(T_A @ T_world_ee, T_B @ T_world_ee, _carry_fraction(positions, close, release))
    actions = vectors_from_poses(T_world_planned, gripper_open).astype(np.float32)
    T_per_action = T_world_planned @ np.linalg.inv(T_world_ee)
    return ReplayPlan(task=task, demo_index=demo_index, T_now_demo=T_A, actions=actions, registration=fits[0],
                      T_now_demo_per_action=T_per_action, object_fits=tuple(fits))


def _plan_anchored(
    task: str,
    demo_index: int,
    demo: ReplaySource,
    live_objects: list[np.ndarray],
    config: RegistrationConfig,
) -> ReplayPlan | None:
    """The anchored plan of one demonstration (module docstring), or None where its segments approach no object or
    the live cloud shows none."""
    demo_objects = split_objects(demo.first_cloud)
    segments = anchor_segments(demo.action, demo_objects, SegmentConfig()) if live_objects else None
    if segments is None:
        return None
    ends, anchors = segments.anchored()
    used = sorted(set(anchors.tolist()))
    fits = dict(zip(used, _match_objects([demo_objects[index] for index in used], live_objects, config), strict=True))
    T_anchor = np.stack([fits[anchor].T_target_source for anchor in anchors])  # (A, 4, 4)
    T_world_ee, gripper_open = poses_from_vectors(demo.action)
    T_world_planned = T_anchor[np.minimum(np.searchsorted(ends, np.arange(len(T_world_ee))), len(ends) - 1)] @ T_world_ee
    for index in np.flatnonzero(anchors[1:] != anchors[:-1]):
        start, end = int(ends[index]), int(ends[index + 1])
        weights = _carry_fraction(demo.action[:, :3], start, end)[start + 1:end + 1]
        T_world_planned[start + 1:end + 1] = _blend(T_anchor[index] @ T_world_ee[start + 1:end + 1],
                                                    T_anchor[index + 1] @ T_world_ee[start + 1:end + 1], weights)
    actions = vectors_from_poses(T_world_planned, gripper_open).astype(np.float32)
    T_per_action = T_world_planned @ np.linalg.inv(T_world_ee)
    first = fits[int(anchors[0])]
    return ReplayPlan(task=task, demo_index=demo_index, T_now_demo=first.T_target_source, actions=actions,
                      registration=first, T_now_demo_per_action=T_per_action,
                      object_fits=tuple(fits[index] for index in used))


def _plan_whole(
    task: str, demo_index: int, demo: ReplaySource, cloud_now: np.ndarray, config: RegistrationConfig
) -> ReplayPlan:
    """The whole-cloud plan of one demonstration: its first cloud registered onto ``cloud_now``, every action moved by
    that one motion."""
    fit = register_rigid(demo.first_cloud, cloud_now, config)
    return ReplayPlan(task=task, demo_index=demo_index, T_now_demo=fit.T_target_source,
                      actions=transform_pose_actions(fit.T_target_source, demo.action), registration=fit)


def _match_objects(
    demo_objects: list[np.ndarray], live_objects: list[np.ndarray], config: RegistrationConfig
) -> list[RegistrationResult]:
    """Register each demonstrated object onto every live object and keep the one-to-one assignment with the least
    summed fit error (Hungarian); the fits of ``demo_objects`` in their order. Where there are more demonstrated
    objects than live ones, those left unassigned take the live object they fit best."""
    fits = [[register_rigid(source, target, config) for target in live_objects] for source in demo_objects]
    errors = np.array([[fit.fit_error for fit in row] for row in fits])
    chosen = np.argmin(errors, axis=1)
    rows, columns = linear_sum_assignment(errors)
    chosen[rows] = columns
    return [fits[row][column] for row, column in enumerate(chosen)]


def _carry_fraction(positions: np.ndarray, close: int, release: int) -> np.ndarray:
    """``(F,)``: 0 up to action ``close``, 1 from action ``release`` on, and between them the fraction of the path of
    the demonstrated positions ``(F, 3)`` from ``close`` to ``release`` travelled (0 where the gripper did not move)."""
    steps = np.linalg.norm(np.diff(positions[close:release + 1], axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    fraction = np.ones(len(positions))
    fraction[:close] = 0.0
    fraction[close:release + 1] = travelled / travelled[-1] if travelled[-1] > 0 else 1.0
    return fraction


def _blend(T_first: np.ndarray, T_second: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Poses ``(F, 4, 4)`` from ``T_first`` (weight 0) to ``T_second`` (weight 1), per pose: the position linearly, the
    rotation along the shortest arc (slerp)."""
    blended = T_first.copy()
    blended[:, :3, 3] = (1.0 - weights)[:, None] * T_first[:, :3, 3] + weights[:, None] * T_second[:, :3, 3]
    relative = Rotation.from_matrix(np.swapaxes(T_first[:, :3, :3], 1, 2) @ T_second[:, :3, :3]).as_rotvec()
    blended[:, :3, :3] = T_first[:, :3, :3] @ Rotation.from_rotvec(weights[:, None] * relative).as_matrix()
    return blended


# The structured planners by plan name; either returns None where the demonstration or the scene lacks its structure.
_STRUCTURED = {"per_object": _plan_per_object, "anchored": _plan_anchored}


def transform_pose_actions(T_now_demo: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Move absolute EE-pose actions ``(F, 8)`` (xyz, quaternion xyzw, gripper) by ``T_now_demo (4, 4)``.

    Each commanded ``T_world_ee`` becomes ``T_now_demo @ T_world_ee``; the gripper command is kept. Quaternions
    come out normalised with ``w >= 0``.
    """
    T_world_ee, gripper_open = poses_from_vectors(actions)
    return vectors_from_poses(T_now_demo @ T_world_ee, gripper_open).astype(np.float32)
