"""Fixed-size point-cloud resampling (numpy side, used by data generation and the simulator)."""

from __future__ import annotations

import fpsample
import numpy as np


def resample_indices(points: np.ndarray, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(num_points,)`` that reduce or pad ``points (P, 3)`` to exactly ``num_points``.

    More points than needed: farthest-point sampling (bucket FPS from a start point drawn from ``rng``).
    Fewer: every point once, then random repeats. An empty cloud is an error.
    """
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (P, 3), got {points.shape}")
    count = points.shape[0]
    if count == 0:
        raise ValueError("cannot resample an empty point cloud")
    if count > num_points:
        start = int(rng.integers(count))
        return np.asarray(fpsample.bucket_fps_kdline_sampling(points, num_points, h=5, start_idx=start))
    if count < num_points:
        return np.concatenate([np.arange(count), rng.integers(0, count, num_points - count)])
    return np.arange(count)


def resample_points(points: np.ndarray, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """``points (P, 3)`` reduced or padded to ``(num_points, 3)`` float32 (see ``resample_indices``)."""
    return np.ascontiguousarray(points[resample_indices(points, num_points, rng)], dtype=np.float32)
