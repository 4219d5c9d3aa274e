"""The replay prior of a held-out live frame, for the offline action error of a policy that starts its denoising from
the replay of its demonstrations (``InstantPolicyConfig.replay_init_strength``).

On a robot, the policy plans the replay once, from the episode's first cloud (:func:`~..data.replay_plan.
plan_replay`, :data:`~..data.replay_plan.REPLAY_REGISTRATION`), and at control step ``k`` starts from planned actions
``k … k + T − 1``: the robot has followed the plan so far, so its progress is the plan's step. A held-out frame ``t``
of a recorded live episode was reached at another demonstrator's pace, so its plan step is where the plan has got to
the live episode's state: :func:`plan_steps` aligns the live EE positions with the planned ones by dynamic time
warping (monotone in both, every frame matched), and frame ``t`` takes the earliest plan step matched to it. The
prior of frame ``t`` is then the plan's actions from that step, the guess the policy is handed
(``predict_action_chunk(initial_actions=...)``), and its own error is the replay's reference.
"""

from __future__ import annotations

import numpy as np

from ..data.demonstrations import Demonstration
from ..data.replay_plan import REPLAY_REGISTRATION, ReplayPlan, plan_replay

# A gripper state that differs from the plan's costs as much as this many metres of EE position in the alignment.
GRIPPER_MISMATCH_M = 0.05


def plan_steps(live_state: np.ndarray, planned: np.ndarray) -> np.ndarray:
    """For every frame of a live episode, ``live_state (F, 8)``, the earliest step of the plan ``planned (G, 8)``
    (both world frame, the contract's layout) that dynamic time warping matches it to, ``(F,)`` int64, non-decreasing,
    0 for the first frame and ``G − 1`` for the last. The cost of matching frame ``i`` to step ``j`` is the distance
    of their EE positions plus :data:`GRIPPER_MISMATCH_M` where their gripper states differ (the plan's command at
    ``j`` against the live state at ``i``)."""
    cost = np.linalg.norm(live_state[:, None, :3] - planned[None, :, :3], axis=-1)
    cost += GRIPPER_MISMATCH_M * ((live_state[:, None, 7] > 0.5) != (planned[None, :, 7] > 0.5))
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
        step = int(np.argmin(moves))
        i, j = (i - 1, j - 1) if step == 0 else (i - 1, j) if step == 1 else (i, j - 1)
    return earliest


def plan_onto_live(demonstrations: list[Demonstration], live_first_points: np.ndarray, plan: str) -> ReplayPlan:
    """The ``plan`` replay (:data:`~..data.replay_plan.REPLAY_PLANS`) of ``demonstrations`` onto the live episode's
    first cloud ``live_first_points (P, 3)``, with the registration inference uses."""
    task = demonstrations[0].task if demonstrations else ""
    return plan_replay(task, demonstrations, live_first_points, REPLAY_REGISTRATION, plan)


def replay_priors(planned: ReplayPlan, live_state: np.ndarray, frames: list[int], horizon: int) -> np.ndarray:
    """The replay prior of live frames ``frames``, ``(len(frames), T, 8)`` world frame: the ``planned`` actions
    (:func:`plan_onto_live`) from the plan step of each frame (:func:`plan_steps` on ``live_state (F, 8)``)."""
    matched = plan_steps(live_state, planned.actions)
    return np.stack([planned.actions_from(int(matched[t]), horizon) for t in frames]).astype(np.float32)


__all__ = ["GRIPPER_MISMATCH_M", "plan_onto_live", "plan_steps", "replay_priors"]
