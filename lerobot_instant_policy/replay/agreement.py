"""How far a task's demonstrations, each planned into the live scene on its own, agree on the path there.

Two demonstrations of a task, each registered rightly, lie on one path in the live scene up to the demonstrators'
own variation; a wrong registration (a symmetric object's flipped yaw, a segment on the wrong object) moves one
plan's bottlenecks off the other's path. :func:`path_disagreement` measures that for two plans' actions: the
largest distance (m) from a bottleneck of one to the nearest planned position of the other, taken both ways. A
plan's bottlenecks are the segment ends where it acts (:func:`~.segments.acting_ends`): its gripper changes, its
stops (a press, a push's end, a wait) and its last action; its turns are left out (a turn in transit, over a carry
between two objects, is where two right plans may part). It is timing-free: two demonstrators who took the same path
at different paces agree. :func:`plans_disagreement` is the largest over every pair of one task's plans (0 for one).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations

import numpy as np

from .segments import acting_ends


def path_disagreement(first: np.ndarray, second: np.ndarray) -> float:
    """The largest distance (m) from a bottleneck of either of two plans' actions ``(F, 8)`` (world frame) to the
    nearest planned position of the other (module docstring)."""

    def one_way(source: np.ndarray, target: np.ndarray) -> float:
        bottlenecks = source[sorted(acting_ends(source)), :3]
        distances = np.linalg.norm(bottlenecks[:, None, :] - target[None, :, :3], axis=-1)
        return float(distances.min(axis=1).max())

    first, second = np.asarray(first, dtype=np.float64), np.asarray(second, dtype=np.float64)
    return max(one_way(first, second), one_way(second, first))


def plans_disagreement(actions: Sequence[np.ndarray]) -> float:
    """The largest :func:`path_disagreement` (m) over every pair of one task's planned ``actions`` (each ``(F, 8)``,
    world frame, one per demonstration); 0 with fewer than two."""
    return max((path_disagreement(first, second) for first, second in combinations(actions, 2)), default=0.0)


__all__ = ["path_disagreement", "plans_disagreement"]
