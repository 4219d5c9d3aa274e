"""How far a replay plan can be trusted, read off the live scene and the demonstrations alone (no ground truth): how
well its registration fits, and how far the demonstrations agree once each is planned into the live scene.

* ``fit_m``: the chosen plan's :attr:`~.plan.ReplayPlan.fit_error`, the mean nearest-neighbour distance (m) between
  the registered demonstration objects and the live ones, both ways.
* ``disagreement_m``: every demonstration planned on its own onto the live cloud (:func:`~.plan.plan_each`), the
  largest distance (m) from a bottleneck of one plan to the other's path (:func:`~.agreement.plans_disagreement`).
  With one demonstration there is nothing to compare: 0.

:func:`trusted_strength` turns the two into the SDEdit strength a prediction starts from
(``InstantPolicyConfig.replay_trust_m``): the plan's distrust ``max(fit_m, disagreement_m)`` below the range's
start keeps the configured ``replay_init_strength``; above its end the denoising starts from noise (strength 1, the
network's own path); in between the strength rises linearly.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .agreement import plans_disagreement
from .plan import ReplayPlan


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
    return PlanTrust(fit_m=chosen.fit_error, disagreement_m=plans_disagreement([plan.actions for plan in plans]))


def trusted_strength(trust: PlanTrust, strength: float, distrust_range_m: tuple[float, float]) -> float:
    """The SDEdit strength in ``[strength, 1]`` for a plan of ``trust`` (module docstring): ``strength`` up to
    ``distrust_range_m[0]``, 1 from ``distrust_range_m[1]`` on, linear between."""
    low, high = distrust_range_m
    if not 0.0 <= low < high:
        raise ValueError(f"the distrust range must be 0 ≤ start < end (m), got {distrust_range_m}")
    rise = float(np.clip((trust.distrust_m - low) / (high - low), 0.0, 1.0))
    return strength + (1.0 - strength) * rise


__all__ = ["PlanTrust", "plan_trust", "trusted_strength"]
