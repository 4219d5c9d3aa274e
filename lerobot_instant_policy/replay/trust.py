"""How far a replay plan can be trusted, read off the live scene and the demonstrations alone (no ground truth): how
well its registration fits, and how far the demonstrations agree once each is planned into the live scene.

* ``fit_m``: the chosen plan's :attr:`~.plan.ReplayPlan.fit_error`, the mean nearest-neighbour distance (m) between
  the registered demonstration objects and the live ones, both ways.
* ``disagreement_m``: every demonstration planned on its own onto the live cloud (:func:`~.plan.plan_each`); for
  each pair of plans, the largest distance (m) from a bottleneck of one to the nearest planned position of the other,
  taken both ways; the largest over pairs. A plan's bottlenecks are the segment ends where it acts
  (:func:`~.segments.acting_ends`): its gripper changes, its stops (a press, a push's end, a wait) and its last
  action; its turns are left out (a turn in transit, over a carry between two objects, is where two right plans may
  part). Timing-free: two demonstrators who took the same path at different paces agree. Two demonstrations of a task,
  each registered rightly, lie on one path up to the demonstrators' own variation; a wrong registration (a symmetric
  object's flipped yaw, a segment on the wrong object) moves one plan's bottlenecks off the other's path. With one
  demonstration there is nothing to compare: 0.

:func:`trusted_strength` turns the two into the SDEdit strength a prediction starts from
(``InstantPolicyConfig.replay_trust_m``): the plan's distrust ``max(fit_m, disagreement_m)`` below the range's
start keeps the configured ``replay_init_strength``; above its end the denoising starts from noise (strength 1, the
network's own path); in between the strength rises linearly.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations
from typing import NamedTuple

import numpy as np

from .plan import ReplayPlan
from .segments import acting_ends


class PlanTrust(NamedTuple):
    """A plan's ``fit_m`` and the demonstrations' ``disagreement_m`` (module docstring), metres."""

    fit_m: float
    disagreement_m: float

    @property
    def distrust_m(self) -> float:
        """The larger of the two (m): what :func:`trusted_strength` reads."""
        return max(self.fit_m, self.disagreement_m)


def plan_trust(plans: Sequence[ReplayPlan], chosen: ReplayPlan) -> PlanTrust:
    """The trust of ``chosen`` among one task's ``plans`` (each demonstration's, :func:`~.plan.plan_each`)."""
    disagreement = max((path_disagreement(first.actions, second.actions) for first, second in combinations(plans, 2)),
                       default=0.0)
    return PlanTrust(fit_m=chosen.fit_error, disagreement_m=disagreement)


def path_disagreement(first: np.ndarray, second: np.ndarray) -> float:
    """The largest distance (m) from a bottleneck of either of two plans' actions ``(F, 8)`` (world frame) to the
    nearest planned position of the other (module docstring)."""

    def one_way(source: np.ndarray, target: np.ndarray) -> float:
        bottlenecks = source[sorted(acting_ends(source)), :3]
        distances = np.linalg.norm(bottlenecks[:, None, :] - target[None, :, :3], axis=-1)
        return float(distances.min(axis=1).max())

    first, second = np.asarray(first, dtype=np.float64), np.asarray(second, dtype=np.float64)
    return max(one_way(first, second), one_way(second, first))


def trusted_strength(trust: PlanTrust, strength: float, distrust_range_m: tuple[float, float]) -> float:
    """The SDEdit strength in ``[strength, 1]`` for a plan of ``trust`` (module docstring): ``strength`` up to
    ``distrust_range_m[0]``, 1 from ``distrust_range_m[1]`` on, linear between."""
    low, high = distrust_range_m
    if not 0.0 <= low < high:
        raise ValueError(f"the distrust range must be 0 ≤ start < end (m), got {distrust_range_m}")
    rise = float(np.clip((trust.distrust_m - low) / (high - low), 0.0, 1.0))
    return strength + (1.0 - strength) * rise


__all__ = ["PlanTrust", "path_disagreement", "plan_trust", "trusted_strength"]
