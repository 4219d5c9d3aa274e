"""Randomisation shared by the built-in tasks: positions in a tabletop region, yaw within ±60°."""

from __future__ import annotations

import numpy as np

MAX_YAW = np.radians(60.0)
X_RANGE = (0.42, 0.62)
Y_RANGE = (-0.2, 0.2)
BLOCK_HALF = 0.02


def sample_yaw(rng: np.random.Generator) -> float:
    return float(rng.uniform(-MAX_YAW, MAX_YAW))


def sample_positions(
    rng: np.random.Generator,
    count: int,
    min_distance: float,
    x_range: tuple[float, float] = X_RANGE,
    y_range: tuple[float, float] = Y_RANGE,
) -> list[np.ndarray]:
    """``count`` xy positions ``(2,)`` in the region, pairwise at least ``min_distance`` apart."""
    for _ in range(1000):
        points = rng.uniform((x_range[0], y_range[0]), (x_range[1], y_range[1]), size=(count, 2))
        gaps = np.linalg.norm(points[:, None] - points[None], axis=-1) + np.eye(count) * 1e9
        if gaps.min() >= min_distance:
            return list(points)
    raise RuntimeError(f"cannot place {count} objects {min_distance} m apart in {x_range} x {y_range}")


def planar_yaw(pose: np.ndarray) -> float:
    """Yaw (rad) of a ``(4, 4)`` pose's x axis in the world xy plane."""
    return float(np.arctan2(pose[1, 0], pose[0, 0]))
