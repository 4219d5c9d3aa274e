"""Paired comparison of two columns evaluated on the same episodes: the difference in success rate with a cluster
bootstrap interval.

Episodes of one task and demonstration set are not independent draws (a set a policy reads badly fails most of its
episodes), so the resampling unit is the cell (task × demonstration set; ``evaluation.manifest``), not the episode.
For columns A and B with the same cells and seeds, cell c holds ``d_c = (successes of A − successes of B)`` over its
``n_c`` episodes, and the difference in success rate is

    Δ = Σ_c d_c / Σ_c n_c.

The interval resamples the cells with replacement ``resamples`` times (a seeded generator) and takes the 2.5th and
97.5th percentiles of Δ over the resamples (the percentile bootstrap). "A beats B" is said only where the whole
interval lies above zero, "B beats A" where it lies below, "no difference shown" otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .manifest import CellOutcome, ManifestError

RESAMPLES = 10_000
CONFIDENCE = 0.95


@dataclass(frozen=True)
class PairedDifference:
    """Δ = rate(A) − rate(B) over ``episodes`` paired episodes in ``cells`` cells, with its bootstrap interval."""

    a: str
    b: str
    cells: int
    episodes: int
    difference: float
    low: float
    high: float

    @property
    def verdict(self) -> str:
        if self.low > 0:
            return f"{self.a} beats {self.b}"
        if self.high < 0:
            return f"{self.b} beats {self.a}"
        return "no difference shown"

    def as_json(self) -> dict:
        return {"a": self.a, "b": self.b, "cells": self.cells, "episodes": self.episodes,
                "difference": self.difference, "ci95_low": self.low, "ci95_high": self.high,
                "interval": "cluster bootstrap over task x demonstration-set cells", "verdict": self.verdict}

    def line(self) -> str:
        return (f"{self.a} - {self.b}: {100 * self.difference:+.1f} points [{100 * self.low:+.1f}, "
                f"{100 * self.high:+.1f}] over {self.episodes} paired episodes in {self.cells} cells: {self.verdict}")


def paired_difference(a: str, cells_a: dict[tuple[str, int], CellOutcome], b: str,
                      cells_b: dict[tuple[str, int], CellOutcome], resamples: int = RESAMPLES,
                      seed: int = 0) -> PairedDifference:
    """Δ of column ``a`` over column ``b`` (module docstring); their cells must be the same, on the same seeds
    (``ManifestError`` otherwise)."""
    if set(cells_a) != set(cells_b) or not cells_a:
        raise ManifestError(f"{a!r} and {b!r} must hold the same non-empty cells to be paired")
    keys = sorted(cells_a)
    for key in keys:
        if cells_a[key].eval_seeds != cells_b[key].eval_seeds:
            raise ManifestError(f"{key[0]}, set {key[1]}: {a!r} and {b!r} ran different seeds; they cannot be paired")
    differences = np.array([sum(cells_a[key].successes) - sum(cells_b[key].successes) for key in keys], dtype=float)
    episodes = np.array([len(cells_a[key].successes) for key in keys], dtype=float)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(keys), size=(resamples, len(keys)))
    resampled = differences[draws].sum(axis=1) / episodes[draws].sum(axis=1)
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(resampled, [tail, 100 - tail])
    return PairedDifference(a, b, len(keys), int(episodes.sum()), float(differences.sum() / episodes.sum()),
                            float(low), float(high))
