"""The one timing model of a replay: the plan step a live episode has reached at each of its frames, and the plan
steps a replay prior reads from there.

A replay plan (:class:`~.plan.ReplayPlan`) is ``G`` actions ``(G, 8)`` (world frame, the contract's layout), each
the EE pose commanded for the next step. A robot following it executes action ``a_k`` at plan step ``k`` from the
pose ``a_{k−1}`` commanded, so the pose it has reached at step ``k`` is ``a_{k−1}``; at step 0 it stands at the
plan's start, which the plan holds only as the pose its first action leads to, ``a_0``, one step on (not the live
episode's start: a live demonstrator that starts elsewhere is matched to the plan's path as it approaches it, not
held at step 0 while it stays near its own start). :func:`plan_steps` aligns a live episode's states ``(F, 8)``
with those reached poses by dynamic time warping (monotone in both, every frame and step matched, the first frame
to step 0 and the last to step ``G − 1``): an episode that executed the plan exactly is at step ``t`` at its frame
``t``; one recorded at another demonstrator's pace (its own start pose, path lengths and stops) is at the step where
the plan has got to its state.

:func:`prior_steps` gives the steps a prior reads: at plan step ``k`` the ``T`` actions ``k … k + T − 1``, the last
action held past the plan's end. Inference reads the plan by control step (the robot has followed the plan, so its
control step is its plan step); the offline validation and the training stream read it at :func:`plan_steps` of
each live frame, optionally ``δ`` steps off (a robot behind the plan, ``δ > 0``, is handed actions of a moment it has
not reached, one ahead of it, ``δ < 0``, of one it has passed).
"""

from __future__ import annotations

import numpy as np

# A gripper state that differs from the plan's costs as much as this many metres of EE position in the alignment.
GRIPPER_MISMATCH_M = 0.05
# The name of this timing model, for results cached by how they were measured (workbench/standing.py's validation).
TIMING_MODEL = "plan_steps: DTW of the live state against the pose reached at each plan step"


def plan_steps(live_state: np.ndarray, planned: np.ndarray) -> np.ndarray:
    """For every frame of a live episode, ``live_state (F, 8)``, the earliest step of the plan ``planned (G, 8)``
    (both world frame, the contract's layout) that dynamic time warping matches it to, ``(F,)`` int64,
    non-decreasing, 0 for the first frame and ``G − 1`` for the last. Step ``k`` stands for the pose the plan has
    reached there (module docstring): ``planned[k − 1]``, and for step 0 ``planned[0]``. The cost of matching frame
    ``i`` to step ``k`` is the distance between the EE position of ``live_state[i]`` and that reached pose, plus
    :data:`GRIPPER_MISMATCH_M` where their gripper states (thresholded at 0.5) differ."""
    live_state, planned = np.asarray(live_state, dtype=np.float64), np.asarray(planned, dtype=np.float64)
    reached = np.concatenate([planned[:1], planned[:-1]])  # (G, 8): the pose at each plan step
    cost = np.linalg.norm(live_state[:, None, :3] - reached[None, :, :3], axis=-1)
    cost += GRIPPER_MISMATCH_M * ((live_state[:, None, 7] > 0.5) != (reached[None, :, 7] > 0.5))
    frames, steps = cost.shape
    total = np.full((frames + 1, steps + 1), np.inf)
    total[0, 0] = 0.0
    for i in range(1, frames + 1):
        row, above = total[i], total[i - 1]
        diagonal_or_above = np.minimum(above[1:], above[:-1]) + cost[i - 1]
        for j in range(1, steps + 1):  # the left neighbour is this row's: a running recurrence
            row[j] = min(diagonal_or_above[j - 1], row[j - 1] + cost[i - 1, j - 1])
    earliest = np.full(frames, steps - 1, dtype=np.int64)
    i, j = frames, steps
    while i > 0 and j > 0:
        earliest[i - 1] = min(earliest[i - 1], j - 1)
        moves = (total[i - 1, j - 1], total[i - 1, j], total[i, j - 1])
        move = int(np.argmin(moves))
        i, j = (i - 1, j - 1) if move == 0 else (i - 1, j) if move == 1 else (i, j - 1)
    return earliest


def prior_steps(steps: np.ndarray, horizon: int, plan_length: int, shifts: np.ndarray | None = None) -> np.ndarray:
    """The plan steps ``(S, T)`` int64 a prior reads at plan steps ``steps (S,)``: ``k + δ … k + δ + T − 1`` for
    step ``k``, ``T = horizon``, each clamped to ``0 … plan_length − 1`` (past the plan's end its last action
    holds); ``shifts (S,)`` int the timing errors ``δ`` in steps (module docstring), None: none."""
    start = np.asarray(steps, dtype=np.int64)
    if shifts is not None:
        start = start + np.asarray(shifts, dtype=np.int64)
    return np.clip(start[:, None] + np.arange(horizon), 0, plan_length - 1)


__all__ = ["GRIPPER_MISMATCH_M", "TIMING_MODEL", "plan_steps", "prior_steps"]
