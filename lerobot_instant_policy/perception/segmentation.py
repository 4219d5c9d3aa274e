"""Segmenting the task objects out of a fused scene cloud without learned weights.

Each function takes world-frame ``points (P, 3)`` and returns a ``keep (P,)`` bool mask, so they compose by
``&``: a workspace box, the table plane (RANSAC), and the gripper as a box around the EE pose. Removing the
robot's links posed by its joint state is ``perception.robot_model``.
"""

from __future__ import annotations

import numpy as np

from ..geometry.se3 import invert, transform_points


class EmptyPointCloudError(RuntimeError):
    """No point of the task objects is left after segmentation: no action may be computed from such a frame."""


def inside_box(points: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``(P,)`` True for points inside the axis-aligned box ``[low, high]`` (world frame, m)."""
    return np.all((points >= np.asarray(low)) & (points <= np.asarray(high)), axis=1)


def fit_horizontal_plane(
    points: np.ndarray,
    rng: np.random.Generator,
    distance_threshold: float,
    iterations: int = 200,
    max_tilt_deg: float = 20.0,
    max_samples: int = 8192,
) -> tuple[np.ndarray, float, float] | None:
    """RANSAC: the plane ``normal · p = offset`` with the most points within ``distance_threshold``, among planes
    whose normal is within ``max_tilt_deg`` of the world z axis (a table seen through a correct calibration).

    Hypotheses are scored on at most ``max_samples`` points drawn from ``points (P, 3)``; the winner is refit by
    least squares to its inliers. Returns ``(normal (3,) with normal_z > 0, offset, inlier fraction)`` or ``None``
    when fewer than 3 points are given.
    """
    if len(points) < 3:
        return None
    sample = points[rng.choice(len(points), min(len(points), max_samples), replace=False)].astype(np.float64)
    triples = sample[rng.integers(0, len(sample), (iterations, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    usable = lengths > 1e-9
    normals = normals[usable] / lengths[usable, None]
    normals *= np.sign(normals[:, 2:3] + 1e-12)
    anchors = triples[usable, 0]
    level = normals[:, 2] >= np.cos(np.radians(max_tilt_deg))
    normals, anchors = normals[level], anchors[level]
    if len(normals) == 0:
        return None
    offsets = np.einsum("ij,ij->i", normals, anchors)
    counts = (np.abs(sample @ normals.T - offsets) < distance_threshold).sum(axis=0)
    best = int(np.argmax(counts))
    inliers = sample[np.abs(sample @ normals[best] - offsets[best]) < distance_threshold]
    centre = inliers.mean(axis=0)
    normal = np.linalg.svd(inliers - centre, full_matrices=False)[2][-1]
    normal *= np.sign(normal[2] + 1e-12)
    if normal[2] < np.cos(np.radians(max_tilt_deg)):
        normal = normals[best]
    return normal, float(normal @ centre), counts[best] / len(sample)


def above_plane(points: np.ndarray, normal: np.ndarray, offset: float, distance_threshold: float) -> np.ndarray:
    """``(P,)`` True for points more than ``distance_threshold`` above the plane (on the side ``normal`` points to)."""
    return points.astype(np.float64) @ normal - offset > distance_threshold


def outside_gripper_box(points: np.ndarray, T_world_ee: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``(P,)`` True for points outside the box ``[low, high]`` given in the EE frame (the gripper's body)."""
    in_ee = transform_points(invert(T_world_ee), points.astype(np.float64))
    return ~inside_box(in_ee, low, high)
