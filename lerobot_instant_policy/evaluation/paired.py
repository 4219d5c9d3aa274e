"""Paired comparison of two columns evaluated on the same episodes: the difference in success rate with a cluster
bootstrap interval.

Episodes of one task are not independent draws (a task a policy cannot do fails in every set; a set a policy reads
badly fails most of its episodes), so the resampling unit is a cluster of episodes, not the episode: by default the
task (``unit="task"``, the unit a reader generalises over: other tasks like these), or the cell (``unit="cell"``:
task × demonstration set, ``evaluation.manifest``), which treats the sets of one task as independent and so gives
a narrower interval. For columns A and B with the same cells and seeds, cluster k holds ``d_k = (successes of A −
successes of B)`` over its ``n_k`` episodes, and the difference in success rate is

    Δ = Σ_k d_k / Σ_k n_k.

The interval resamples the clusters with replacement ``resamples`` times (a generator seeded ``seed``: the same
cells give the same interval) and takes the 2.5th and 97.5th percentiles of Δ over the resamples (the percentile
bootstrap). With a single cluster there is nothing to resample: the interval is NaN. "A beats B" is said only where
the whole interval lies above zero, "B beats A" where it lies below, "no difference shown" otherwise.

Beside Δ, the discordant episodes say how it arises: ``a_only``, the episodes A succeeds in and B fails, and
``b_only``, the reverse (``Δ = (a_only − b_only) / episodes``). Where B is the plan A starts from, they count the
plan's failures A mends and its successes A breaks; two columns level in Δ may agree episode for episode or trade
many episodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bootstrap import cluster_bootstrap
from .manifest import CellOutcome, ManifestError

RESAMPLES = 10_000
UNITS = ("task", "cell")  # what the bootstrap resamples (module docstring)


@dataclass(frozen=True)
class PairedDifference:
    """Δ = rate(A) − rate(B) over ``episodes`` paired episodes in ``cells`` cells, with its bootstrap interval over
    ``clusters`` clusters of ``unit`` (``task`` or ``cell``), and the discordant episodes ``a_only`` (A succeeds, B
    fails) and ``b_only`` (the reverse)."""

    a: str
    b: str
    cells: int
    episodes: int
    difference: float
    low: float
    high: float
    unit: str = "task"
    clusters: int = 0
    a_only: int = 0
    b_only: int = 0

    @property
    def verdict(self) -> str:
        if self.low > 0:
            return f"{self.a} beats {self.b}"
        if self.high < 0:
            return f"{self.b} beats {self.a}"
        return "no difference shown"

    def as_json(self) -> dict:
        unit = "tasks" if self.unit == "task" else "task x demonstration-set cells"
        return {"a": self.a, "b": self.b, "cells": self.cells, "episodes": self.episodes,
                "difference": self.difference, "ci95_low": None if np.isnan(self.low) else self.low,
                "ci95_high": None if np.isnan(self.high) else self.high, "unit": self.unit,
                "clusters": self.clusters, "interval": f"cluster bootstrap over {unit}", "verdict": self.verdict,
                "a_only_successes": self.a_only, "b_only_successes": self.b_only}

    def line(self) -> str:
        return (f"{self.a} - {self.b}: {100 * self.difference:+.1f} points [{100 * self.low:+.1f}, "
                f"{100 * self.high:+.1f}] over {self.episodes} paired episodes, {self.clusters} {self.unit}s "
                f"resampled ({self.cells} cells): {self.verdict}; {self.a} alone succeeds in {self.a_only}, "
                f"{self.b} alone in {self.b_only}")


def paired_difference(a: str, cells_a: dict[tuple[str, int], CellOutcome], b: str,
                      cells_b: dict[tuple[str, int], CellOutcome], resamples: int = RESAMPLES,
                      seed: int = 0, unit: str = "task") -> PairedDifference:
    """Δ of column ``a`` over column ``b`` with its interval resampling ``unit`` (module docstring); their cells
    must be the same, on the same seeds (``ManifestError`` otherwise)."""
    if unit not in UNITS:
        raise ValueError(f"unit must be one of {list(UNITS)}, got {unit!r}")
    if set(cells_a) != set(cells_b) or not cells_a:
        raise ManifestError(f"{a!r} and {b!r} must hold the same non-empty cells to be paired")
    keys = sorted(cells_a)
    for key in keys:
        if cells_a[key].eval_seeds != cells_b[key].eval_seeds:
            raise ManifestError(f"{key[0]}, set {key[1]}: {a!r} and {b!r} ran different seeds; they cannot be paired")
    pairs = [(x, y) for key in keys for x, y in zip(cells_a[key].successes, cells_b[key].successes, strict=True)]
    a_only, b_only = sum(x and not y for x, y in pairs), sum(y and not x for x, y in pairs)
    clusters: dict[tuple, list[int]] = {}
    for key in keys:
        counts = clusters.setdefault(key[:1] if unit == "task" else key, [0, 0])
        counts[0] += sum(cells_a[key].successes) - sum(cells_b[key].successes)
        counts[1] += len(cells_a[key].successes)
    differences = np.array([d for d, _ in clusters.values()], dtype=float)
    episodes = np.array([n for _, n in clusters.values()], dtype=float)
    low, high = cluster_bootstrap(lambda draws: differences[draws].sum(axis=1) / episodes[draws].sum(axis=1),
                                  len(clusters), resamples, seed)
    return PairedDifference(a, b, len(keys), int(episodes.sum()), float(differences.sum() / episodes.sum()),
                            float(low), float(high), unit, len(clusters), int(a_only), int(b_only))
