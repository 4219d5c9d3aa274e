"""Replay priors: the planned actions a policy that starts its denoising from the replay of its demonstrations
(``InstantPolicyConfig.replay_init_strength``) is handed, and those it trains to refine from
(``InstantPolicyConfig.refine_fraction``). Inference, the training stream and the offline validation all make them
here, planned and timed alike.

The plan (:func:`plan_onto_live`) is :func:`~.plan.plan_replay` with the yaw-only registration
(:data:`~.plan.REPLAY_REGISTRATION`) of the demonstrations' first clouds onto the live episode's first cloud, made
once per episode; :func:`plan_onto_live_trusted` also says how far it can be trusted (:mod:`.trust`). A prior is
``(T, 8)`` planned actions read by plan step (:func:`replay_priors`, :func:`~.timing.prior_steps`): at inference
the control step (the robot has followed the plan so far); for a recorded live episode, which another demonstrator
recorded at its own pace, the plan step of each frame (:func:`~.timing.plan_steps` on its states).

Training (:func:`replay_prior_actions`, called by the pseudo-task stream) plans only from the first context
demonstration: a training batch keeps the first N demonstrations of each context (``InstantPolicyPolicy.forward``),
so the first is in every context the network sees, and a plan from another could replay a demonstration the context
does not hold. A robot that does not follow the plan exactly falls behind it or runs ahead, and inference, which
reads the plan by control step, then hands the network the actions of another moment; ``time_shifts`` models that
timing error. The plan is also judged against the live demonstration, the scene's ground truth
(:func:`~.segments.plan_is_wrong`: off at a gripper change or the end, or missing a gripper change), as the replays
a policy meets are judged against their scenes' demonstrations, so the stream can keep wrong priors in the share
those replays are wrong (``StreamConfig.wrong_prior_keep``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..data.demonstrations import Demonstration
from .plan import REPLAY_REGISTRATION, ReplayPlan, ReplaySource, best_plan, plan_each, plan_replay
from .segments import plan_is_wrong
from .timing import plan_steps, prior_steps
from .trust import PlanTrust, plan_trust


def plan_onto_live(task: str, demonstrations: Sequence[Demonstration | ReplaySource], live_first_cloud: np.ndarray,
                   plan: str) -> ReplayPlan:
    """The ``plan`` replay (one of :data:`~.plan.REPLAY_PLANS`) of ``demonstrations`` of ``task`` onto the live
    episode's first cloud ``live_first_cloud (P, 3)`` (world frame), with the registration inference uses."""
    return plan_replay(task, demonstrations, live_first_cloud, REPLAY_REGISTRATION, plan)


def plan_onto_live_trusted(task: str, demonstrations: Sequence[Demonstration | ReplaySource],
                           live_first_cloud: np.ndarray, plan: str) -> tuple[ReplayPlan, PlanTrust]:
    """:func:`plan_onto_live`'s plan and its :class:`~.trust.PlanTrust` among every demonstration's own plan."""
    candidates = plan_each(task, demonstrations, live_first_cloud, REPLAY_REGISTRATION, plan)
    chosen = best_plan(candidates)
    return chosen, plan_trust(candidates, chosen)


def replay_priors(planned: ReplayPlan, steps: np.ndarray, horizon: int, shifts: np.ndarray | None = None
                  ) -> np.ndarray:
    """The priors ``(S, T, 8)`` float32 (world frame, the contract's layout) at plan steps ``steps (S,)``: the
    ``planned`` actions :func:`~.timing.prior_steps` reads there, ``T = horizon``, ``shifts (S,)`` steps off (None:
    on time)."""
    return planned.actions[prior_steps(steps, horizon, len(planned.actions), shifts)].astype(np.float32)


class ReplayPrior(NamedTuple):
    """A live demonstration's replay prior: ``actions (S, T, 8)`` and whether its plan is ``wrong``."""

    actions: np.ndarray
    wrong: bool


def replay_prior_actions(
    source: ReplaySource,
    live_first_cloud: np.ndarray,
    live_state: np.ndarray,
    live_action: np.ndarray,
    live_frames: np.ndarray,
    horizon: int,
    plan: str,
    time_shifts: np.ndarray | None = None,
) -> ReplayPrior:
    """The training prior of live frames ``live_frames (S,)``: ``(S, T, 8)`` world-frame EE targets and gripper
    commands, ``T = horizon``, and whether the whole plan is wrong against the live demonstration (module docstring).

    ``source`` is the first context demonstration (its first cloud as rendered for training, its actions);
    ``live_first_cloud (P, 3)`` the live demonstration's first cloud, ``live_state (F, 8)`` and
    ``live_action (F, 8)`` its states and actions, all world frame. ``plan``: one of :data:`~.plan.REPLAY_PLANS`.
    ``time_shifts (S,)`` int: each frame's timing error in plan steps (None: none)."""
    replay = plan_onto_live("pseudo-task", [source], live_first_cloud, plan)
    steps = plan_steps(live_state, replay.actions)[np.asarray(live_frames)]
    return ReplayPrior(replay_priors(replay, steps, horizon, time_shifts), plan_is_wrong(replay.actions, live_action))


__all__ = ["ReplayPrior", "plan_onto_live", "plan_onto_live_trusted", "replay_prior_actions", "replay_priors"]
