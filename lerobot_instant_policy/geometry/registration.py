"""Rigid registration of two point clouds: principal-axes initialisation refined by trimmed ICP.

``register_rigid(source, target)`` estimates ``T_target_source``, the rigid transform that moves the ``source``
cloud onto the ``target`` cloud. Both clouds are ``(P, 3)`` / ``(Q, 3)`` points in one frame (e.g. the world); they
need not have the same size, sampling or visible part of the object.

1. **Initial guesses.** The centroids give the translation, the principal axes of each cloud a rotation. Principal
   axes are only defined up to sign and, for near-equal spreads, up to order, so every proper rotation that maps
   the source's axes onto the target's (24 signed permutations; 4 quarter turns when the motion is restricted to
   yaw about world z, plus ``yaw_samples`` evenly spaced yaws) is tried.
2. **Coarse ICP** from each guess on a few points; the results are ranked by ``fit_error`` on the finer
   clouds: the mean distance from each cloud to the other, both ways, each distance capped at
   ``inlier_distance``. Unlike the trimmed residual that ICP minimises, it counts a small distinctive part that
   does not match (a mug's handle on the wrong side).
3. **Fine ICP** on more points from the ``refined_candidates`` best; the lowest ``fit_error`` wins.

ICP is point-to-point: nearest neighbours in the target (``scipy.spatial.cKDTree``), the ``overlap`` fraction of
closest pairs kept (trimmed ICP, for partial overlap), then the best rigid transform of those pairs (Kabsch /
SVD through ``scipy.spatial.transform.Rotation.align_vectors``, or its closed form for a yaw about z). The ICP runs
from all guesses of a stage go together, one nearest-neighbour query per iteration, each stopping on its own.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from .sampling import resample_points
from .se3 import make_pose, transform_points


@dataclass(frozen=True)
class RegistrationConfig:
    """Options of ``register_rigid``.

    ``yaw_only``: restrict the rotation to one about world z (upright tabletop objects), else full SE(3).
    ``yaw_samples``: with ``yaw_only``, this many evenly spaced yaws are tried besides the principal-axes ones (a
    partial view can turn the principal axes of an object with a near-round footprint arbitrarily).
    ``overlap``: fraction of the closest correspondences kept at each ICP step (1.0 = plain ICP).
    ``coarse_points`` / ``fine_points``: clouds are reduced to at most this many points (farthest-point sampling)
    for the coarse search over initial guesses and for the final refinement.
    ``refined_candidates``: how many of the best coarse results are refined before the final choice (a nearly
    symmetric object's wrong turn can look as good as the right one until both are refined).
    ``coarse_iterations`` / ``fine_iterations``: ICP iteration limits; ``tolerance`` (m) stops ICP once the
    trimmed residual improves by less.
    ``inlier_distance`` (m): a source point whose nearest target point is closer counts as an inlier.
    """

    yaw_only: bool = False
    yaw_samples: int = 12
    overlap: float = 0.8
    coarse_points: int = 256
    fine_points: int = 1024
    refined_candidates: int = 3
    coarse_iterations: int = 15
    fine_iterations: int = 40
    tolerance: float = 1e-6
    inlier_distance: float = 0.01

    def __post_init__(self) -> None:
        if not 0.0 < self.overlap <= 1.0:
            raise ValueError(f"overlap must be in (0, 1], got {self.overlap}")
        if self.coarse_points < 3 or self.fine_points < 3:
            raise ValueError(f"coarse_points and fine_points must be at least 3, got {self.coarse_points}, {self.fine_points}")
        if self.refined_candidates < 1:
            raise ValueError(f"refined_candidates must be at least 1, got {self.refined_candidates}")
        if self.yaw_samples < 0:
            raise ValueError(f"yaw_samples must be non-negative, got {self.yaw_samples}")
        if self.coarse_iterations < 1 or self.fine_iterations < 1:
            raise ValueError("coarse_iterations and fine_iterations must be at least 1")
        if self.tolerance < 0.0 or self.inlier_distance <= 0.0:
            raise ValueError("tolerance must be non-negative and inlier_distance positive")


@dataclass(frozen=True)
class RegistrationResult:
    """``T_target_source (4, 4)``; ``residual``: RMS distance (m) of the kept (trimmed) correspondences;
    ``fit_error``: mean nearest-neighbour distance (m) between the moved source and the target, both ways, each
    capped at ``inlier_distance``; ``inlier_ratio``: fraction of source points within ``inlier_distance`` of the
    target; ``iterations`` of the fine ICP."""

    T_target_source: np.ndarray
    residual: float
    fit_error: float
    inlier_ratio: float
    iterations: int


def register_rigid(
    source: np.ndarray, target: np.ndarray, config: RegistrationConfig | None = None, seed: int = 0
) -> RegistrationResult:
    """Estimate ``T_target_source`` that moves ``source (P, 3)`` onto ``target (Q, 3)`` (same frame, metres).

    ``seed`` fixes the start points of the farthest-point subsampling, so the result is deterministic. Raises
    ``ValueError`` for clouds that are not ``(N, 3)``, have fewer than 3 points, or contain NaN/inf.
    """
    config = config or RegistrationConfig()
    source = _checked_cloud(source, "source")
    target = _checked_cloud(target, "target")
    rng = np.random.default_rng(seed)
    fine_source = _subsample(source, config.fine_points, rng)
    fine_target = _subsample(target, config.fine_points, rng)
    fine_tree = cKDTree(fine_target)
    coarse_source = _subsample(fine_source, config.coarse_points, rng)
    coarse_target = _subsample(fine_target, config.coarse_points, rng)
    coarse_tree = cKDTree(coarse_target)

    initials = np.stack(_initial_guesses(source, target, config.yaw_only, config.yaw_samples))
    coarse, _, _ = _icp(coarse_source, coarse_tree, coarse_target, initials, config, config.coarse_iterations)
    scores = [_fit_error(pose, fine_source, fine_tree, fine_target, config.inlier_distance)[0] for pose in coarse]
    ranked = coarse[np.argsort(scores, kind="stable")[: config.refined_candidates]]

    poses, residuals, iterations = _icp(fine_source, fine_tree, fine_target, ranked, config, config.fine_iterations)
    best = None
    for pose, residual, count in zip(poses, residuals, iterations, strict=True):
        fit_error, inlier_ratio = _fit_error(pose, fine_source, fine_tree, fine_target, config.inlier_distance)
        if best is None or fit_error < best.fit_error:
            best = RegistrationResult(T_target_source=pose, residual=float(residual), fit_error=fit_error,
                                      inlier_ratio=inlier_ratio, iterations=int(count))
    return best


def _fit_error(
    pose: np.ndarray, source: np.ndarray, target_tree: cKDTree, target: np.ndarray, cap: float
) -> tuple[float, float]:
    """Symmetric capped nearest-neighbour distance (m) of ``pose · source`` and ``target``; source inlier ratio."""
    moved = transform_points(pose, source)
    to_target, _ = target_tree.query(moved, distance_upper_bound=cap)
    to_source, _ = cKDTree(moved).query(target, distance_upper_bound=cap)
    error = 0.5 * (np.minimum(to_target, cap).mean() + np.minimum(to_source, cap).mean())
    return float(error), float(np.mean(to_target < cap))


def _checked_cloud(points: np.ndarray, name: str) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} cloud must have shape (N, 3), got {points.shape}")
    if points.shape[0] < 3:
        raise ValueError(f"{name} cloud needs at least 3 points to register, got {points.shape[0]}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} cloud contains NaN or infinite coordinates")
    return points


def _subsample(points: np.ndarray, num_points: int, rng: np.random.Generator) -> np.ndarray:
    if len(points) <= num_points:
        return points
    return resample_points(points, num_points, rng).astype(np.float64)


def _principal_axes(points: np.ndarray) -> np.ndarray:
    """``(3, 3)`` right-handed matrix whose columns are the principal axes of ``points``, largest spread first."""
    _, eigenvectors = np.linalg.eigh(np.cov(points.T))
    axes = eigenvectors[:, ::-1]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes


def _planar_principal_angle(points: np.ndarray) -> float:
    """Angle (rad) about z of the principal axis of the points' x/y projection."""
    _, eigenvectors = np.linalg.eigh(np.cov(points[:, :2].T))
    major = eigenvectors[:, -1]
    return float(np.arctan2(major[1], major[0]))


def _axis_permutations() -> list[np.ndarray]:
    """The 24 proper rotations that map the coordinate axes onto themselves (signed permutation matrices)."""
    rotations = []
    for order in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            matrix = np.zeros((3, 3))
            matrix[list(order), range(3)] = signs
            if np.linalg.det(matrix) > 0:
                rotations.append(matrix)
    return rotations


_AXIS_PERMUTATIONS = _axis_permutations()


def _initial_guesses(source: np.ndarray, target: np.ndarray, yaw_only: bool, yaw_samples: int) -> list[np.ndarray]:
    """Candidate ``T_target_source`` poses: centroid translation combined with every principal-axes rotation."""
    source_centroid, target_centroid = source.mean(axis=0), target.mean(axis=0)
    if yaw_only:
        base = _planar_principal_angle(target) - _planar_principal_angle(source)
        yaws = [base + quarter * np.pi / 2 for quarter in range(4)]
        yaws += list(np.linspace(-np.pi, np.pi, yaw_samples, endpoint=False))
        rotations = list(_yaw_matrices(np.array(yaws)))
    else:
        source_axes, target_axes = _principal_axes(source), _principal_axes(target)
        rotations = [target_axes @ permutation @ source_axes.T for permutation in _AXIS_PERMUTATIONS]
    return [make_pose(target_centroid - rotation @ source_centroid, rotation) for rotation in rotations]


def _icp(
    source: np.ndarray,
    tree: cKDTree,
    target: np.ndarray,
    initials: np.ndarray,
    config: RegistrationConfig,
    max_iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Trimmed point-to-point ICP from each of ``initials (C, 4, 4)``, all run together (one nearest-neighbour query
    and one batched fit per iteration for the runs still going), each stopping on its own once its trimmed residual
    improves by less than ``config.tolerance``. Returns the poses ``(C, 4, 4)``, their trimmed RMS residuals ``(C,)``
    and the iterations each ran ``(C,)``."""
    keep = max(3, int(round(config.overlap * len(source))))
    poses = np.array(initials, dtype=np.float64)
    previous = np.full(len(poses), np.inf)
    residuals = np.full(len(poses), np.inf)
    iterations = np.full(len(poses), max_iterations)
    running = np.arange(len(poses))
    for iteration in range(1, max_iterations + 1):
        distances, indices = _nearest(poses[running], source, tree)
        kept = np.argpartition(distances, keep - 1, axis=1)[:, :keep]
        residual = np.sqrt(np.mean(np.take_along_axis(distances, kept, axis=1) ** 2, axis=1))
        done = previous[running] - residual < config.tolerance
        residuals[running[done]] = residual[done]
        iterations[running[done]] = iteration
        previous[running] = residual
        running, kept, indices = running[~done], kept[~done], indices[~done]
        if not len(running):
            return poses, residuals, iterations
        matched = target[np.take_along_axis(indices, kept, axis=1)]
        poses[running] = _best_rigid_transforms(source[kept], matched, config.yaw_only)
    distances, _ = _nearest(poses[running], source, tree)
    residuals[running] = np.sqrt(np.mean(np.partition(distances, keep - 1, axis=1)[:, :keep] ** 2, axis=1))
    return poses, residuals, iterations


def _nearest(poses: np.ndarray, source: np.ndarray, tree: cKDTree) -> tuple[np.ndarray, np.ndarray]:
    """Distances and indices ``(R, P)`` of the nearest target point (``tree``) to each point of ``source (P, 3)``
    moved by each of ``poses (R, 4, 4)``."""
    moved = source[None] @ poses[:, :3, :3].transpose(0, 2, 1) + poses[:, None, :3, 3]
    distances, indices = tree.query(moved.reshape(-1, 3))
    return distances.reshape(len(poses), -1), indices.reshape(len(poses), -1)


def _yaw_matrices(yaws: np.ndarray) -> np.ndarray:
    """The rotations by ``yaws (R,)`` (rad) about z, ``(R, 3, 3)``."""
    cos, sin = np.cos(yaws), np.sin(yaws)
    rotations = np.zeros((len(yaws), 3, 3))
    rotations[:, 0, 0], rotations[:, 0, 1], rotations[:, 1, 0], rotations[:, 1, 1] = cos, -sin, sin, cos
    rotations[:, 2, 2] = 1.0
    return rotations


def _best_rigid_transforms(source: np.ndarray, target: np.ndarray, yaw_only: bool) -> np.ndarray:
    """Least-squares ``T`` with ``T · source[r, i] ≈ target[r, i]`` for each row ``r`` of paired points
    ``(R, N, 3)`` (Kabsch), ``(R, 4, 4)``; with ``yaw_only`` the closed-form rotation about z."""
    source_centroid, target_centroid = source.mean(axis=1), target.mean(axis=1)
    source_centred, target_centred = source - source_centroid[:, None], target - target_centroid[:, None]
    if yaw_only:
        sx, sy, tx, ty = source_centred[..., 0], source_centred[..., 1], target_centred[..., 0], target_centred[..., 1]
        cross, dot = np.sum(sx * ty - sy * tx, axis=1), np.sum(sx * tx + sy * ty, axis=1)
        rotations = _yaw_matrices(np.arctan2(cross, dot))
    else:
        rotations = np.stack([Rotation.align_vectors(target_row, source_row)[0].as_matrix()
                              for target_row, source_row in zip(target_centred, source_centred, strict=True)])
    poses = np.zeros((len(source), 4, 4))
    poses[:, :3, :3] = rotations
    poses[:, :3, 3] = target_centroid - np.einsum("rij,rj->ri", rotations, source_centroid)
    poses[:, 3, 3] = 1.0
    return poses
