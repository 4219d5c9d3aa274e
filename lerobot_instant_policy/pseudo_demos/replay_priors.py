"""The replay prior of a pseudo-task's live demonstration: what the ``demo_replay`` plan of its context would have
the robot do at each live frame, the guess that training to refine (``InstantPolicyConfig.refine_fraction``) starts
the denoising from.

The plan is the one inference makes (:func:`~..data.replay_plan.plan_replay`, yaw-only registration, per object or
whole), of the first context demonstration: its first cloud registered onto the live demonstration's first cloud, its
actions moved into the live scene. Only the first, because a training batch draws its N per batch and keeps the
first N demonstrations of each context (``InstantPolicyPolicy.forward``): the first is in every context the network
sees, and a plan from another could replay a demonstration the context does not hold (inference plans from the
demonstrations it is given). It also halves the registrations a generator runs. The plan's actions are then re-timed
to the live demonstration.
At inference the robot follows the plan, so planned action ``k`` is the guess at control step ``k``; in training the
target is another demonstrator's trajectory whose pace differs (its own start pose, path lengths and stops), and the
plan's action at the same frame index would ask the network to re-time the plan as well as correct it. Both
demonstrations pass the task's waypoints in the same order (``DemoPlan.waypoint_frames``), so live frame ``t`` maps
to the planned demonstration's frame by linear interpolation between the frames where the two reach the same
waypoint (first and last frames included): the prior of live frame ``t`` and action ``j`` is the planned action at
the mapped frame of ``t + j``.

A robot that does not follow the plan exactly falls behind it or runs ahead, and inference, which reads the plan by
control step, then hands the network the plan's actions of another moment. ``time_shifts (S,)`` models that timing
error: the prior of live frame ``t`` is read at ``t + δ_t`` (clamped to the episode), ``δ_t`` frames late (> 0) or
early (< 0).

The plan is also judged against the live demonstration, the scene's ground truth
(:func:`~..data.replay_segments.plan_is_wrong`: off at a gripper change or the end, or missing a gripper change), as
the replays a policy meets are judged against their scenes' demonstrations, so the stream can keep wrong priors in
the share those replays are wrong (``StreamConfig.wrong_prior_keep``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..data.replay_plan import REPLAY_REGISTRATION, ReplaySource, plan_replay
from ..data.replay_segments import plan_is_wrong
from .generation import PlannedTask
from .replay import DemoPlan


def aligned_frames(live: DemoPlan, planned: DemoPlan, frames: np.ndarray) -> np.ndarray:
    """The frames of ``planned`` that correspond to ``frames`` (any shape, int) of ``live``: piecewise linear between
    the frames where both reach the same waypoint, rounded; proportional to the episode lengths where the two
    demonstrations do not pass the same number of waypoints."""
    live_last, planned_last = live.num_frames - 1, planned.num_frames - 1
    if len(live.waypoint_frames) == len(planned.waypoint_frames):
        live_knots = np.concatenate([[0], live.waypoint_frames, [live_last]]).astype(float)
        planned_knots = np.concatenate([[0], planned.waypoint_frames, [planned_last]]).astype(float)
        # Waypoints reached on the same frame (a zero-length segment) would make np.interp's knots non-increasing.
        live_knots = np.maximum.accumulate(live_knots)
        mapped = np.interp(np.minimum(frames, live_last), live_knots, planned_knots)
    else:
        mapped = np.minimum(frames, live_last) * (planned_last / max(live_last, 1))
    return np.clip(np.rint(mapped), 0, planned_last).astype(np.int64)


class ReplayPrior(NamedTuple):
    """A live demonstration's replay prior: ``actions (S, T, 8)`` and whether its plan is ``wrong``."""

    actions: np.ndarray
    wrong: bool


def replay_prior_actions(
    planned: PlannedTask,
    context_first_cloud: np.ndarray,
    live_first_cloud: np.ndarray,
    live_frames: np.ndarray,
    horizon: int,
    plan: str,
    time_shifts: np.ndarray | None = None,
) -> ReplayPrior:
    """The replay prior of live frames ``live_frames (S,)``: ``(S, T, 8)`` absolute world-frame EE targets and gripper
    commands (the contract's layout), ``T = horizon``, and whether the whole plan is wrong against the live
    demonstration's actions (module docstring).

    ``planned.demos`` holds the context demonstrations then the live one; ``context_first_cloud (P, 3)`` is the first
    context demonstration's first cloud and ``live_first_cloud (P, 3)`` the live one's, world frame, as rendered for
    training. ``plan``: one of :data:`~..data.replay_plan.REPLAY_PLANS` (module docstring). ``time_shifts (S,)``
    int: each frame's timing error in frames (module docstring); None: none.
    """
    first, live = planned.demos[0], planned.demos[-1]
    source = ReplaySource(np.asarray(context_first_cloud), first.action)
    replay = plan_replay(f"pseudo-task {planned.task_index}", [source], live_first_cloud, REPLAY_REGISTRATION, plan)
    read = np.asarray(live_frames) if time_shifts is None else np.maximum(np.asarray(live_frames) + time_shifts, 0)
    steps = read[:, None] + np.arange(horizon)
    actions = replay.actions[aligned_frames(live, first, steps)].astype(np.float32)
    return ReplayPrior(actions, plan_is_wrong(replay.actions, live.action))


__all__ = ["ReplayPrior", "aligned_frames", "replay_prior_actions"]
