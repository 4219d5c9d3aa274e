"""The percentile cluster bootstrap behind the intervals of ``evaluation``: clusters (tasks, or a task's cells) are
resampled with replacement, the statistic is recomputed on every resample, and the interval is the 2.5th and
97.5th percentiles of the resampled statistic. The success tables (``success_table``), the paired differences of
success rates (``paired``) and the action error's ratios (``action_error``) all draw their resamples here."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

CONFIDENCE = 0.95


def cluster_bootstrap(statistic: Callable[[np.ndarray], np.ndarray], clusters: int, resamples: int,
                      seed: int) -> tuple[float, float]:
    """The percentile bootstrap interval ``(low, high)`` at ``CONFIDENCE`` of a statistic of ``clusters`` clusters:
    ``statistic`` maps ``draws (resamples, clusters)``, the cluster indices of each resample drawn with replacement
    from a generator seeded ``seed``, to the statistic of each resample ``(resamples,)``. NaNs for fewer than two
    clusters (nothing to resample)."""
    if clusters < 2:
        return math.nan, math.nan
    draws = np.random.default_rng(seed).integers(0, clusters, size=(resamples, clusters))
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(statistic(draws), [tail, 100 - tail])
    return float(low), float(high)
