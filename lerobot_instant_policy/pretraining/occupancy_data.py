"""Training data for the geometry encoder's occupancy pretraining (paper appendix A).

A scene is two library objects on the table, rendered exactly like a pseudo-demonstration frame (three depth
cameras, segmentation, the gripper occluding, farthest-point sampling to ``num_points``). Queries lie on and near
the observed surface and in the free space around it; a query is labelled *on surface* when it lies within
``surface_epsilon`` of the true object meshes (distance to a dense area-uniform surface sample). Every scene
draws from its own random stream ``(seed, scene index)``, so a set does not depend on the number of workers.
"""

from __future__ import annotations

import functools
import hashlib
import json
import multiprocessing
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..geometry.sampling import resample_indices
from ..geometry.se3 import transform_points
from ..objects.library import load_object, object_ids
from ..objects.rendering import PointCloudRenderer
from ..pseudo_demos.replay import DemoConfig, sample_layout


@dataclass(frozen=True)
class OccupancyDataConfig:
    """How occupancy scenes and queries are drawn. Distances in metres."""

    num_points: int = 2048
    num_queries: int = 2048
    surface_epsilon: float = 0.01
    surface_noise: float = 0.003
    near_noise: float = 0.02
    free_margin: float = 0.03
    surface_fraction: float = 0.4
    near_fraction: float = 0.4
    dense_samples: int = 16384

    def __post_init__(self):
        if not 0 < self.surface_fraction + self.near_fraction <= 1:
            raise ValueError("surface_fraction + near_fraction must lie in (0, 1]")
        if min(self.num_points, self.num_queries, self.dense_samples) < 1 or self.surface_epsilon <= 0:
            raise ValueError("counts and surface_epsilon must be positive")


@dataclass
class OccupancySet:
    """``points (S, P, 3)``, ``queries (S, Q, 3)`` in the world frame (m), ``labels (S, Q)`` bool (on surface)."""

    points: np.ndarray
    queries: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return len(self.points)

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, points=self.points, queries=self.queries, labels=self.labels)
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> OccupancySet:
        with np.load(path) as arrays:
            return cls(arrays["points"], arrays["queries"], arrays["labels"].astype(bool))


@functools.lru_cache(maxsize=256)
def dense_surface(object_id: str, count: int) -> np.ndarray:
    """``(count, 3)`` area-uniform samples of an object's mesh surface in its own frame (deterministic)."""
    model = load_object(object_id)
    mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=zlib.crc32(object_id.encode()))
    return np.asarray(points, dtype=np.float64)


def sample_queries(
    points: np.ndarray, surface: np.ndarray, rng: np.random.Generator, config: OccupancyDataConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Queries around an observed cloud ``points (P, 3)`` and their labels against ``surface (D, 3)``."""
    num_surface = int(round(config.num_queries * config.surface_fraction))
    num_near = int(round(config.num_queries * config.near_fraction))
    num_free = config.num_queries - num_surface - num_near
    anchors = points[rng.integers(len(points), size=num_surface + num_near)]
    noise = np.concatenate(
        [
            rng.normal(scale=config.surface_noise, size=(num_surface, 3)),
            rng.normal(scale=config.near_noise, size=(num_near, 3)),
        ]
    )
    lower, upper = points.min(axis=0) - config.free_margin, points.max(axis=0) + config.free_margin
    queries = np.concatenate([anchors + noise, rng.uniform(lower, upper, size=(num_free, 3))])
    distance, _ = cKDTree(surface).query(queries)
    return queries.astype(np.float32), distance < config.surface_epsilon


def generate_scene(
    scene_index: int, seed: int, pool: list[str], renderer: PointCloudRenderer, config: OccupancyDataConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One scene: ``points (P, 3)``, ``queries (Q, 3)``, ``labels (Q,)``; redraws until the cloud is non-empty."""
    rng = np.random.default_rng([seed, scene_index])
    for _ in range(20):
        ids = [pool[i] for i in rng.choice(len(pool), size=2, replace=False)]
        objects = [load_object(object_id) for object_id in ids]
        layout = sample_layout(objects, rng, DemoConfig())
        renderer.set_objects(objects)
        cloud, _ = renderer.render(list(layout.T_world_objects), layout.T_world_ee_start, True)
        if len(cloud) >= 16:
            break
    else:
        raise RuntimeError(f"scene {scene_index}: no object visible in 20 layouts")
    points = cloud[resample_indices(cloud, config.num_points, rng)]
    surface = np.concatenate(
        [
            transform_points(T_world_object, dense_surface(object_id, config.dense_samples))
            for object_id, T_world_object in zip(ids, layout.T_world_objects)
        ]
    )
    queries, labels = sample_queries(points.astype(np.float64), surface, rng, config)
    return points.astype(np.float32), queries, labels


def generate_occupancy_set(
    num_scenes: int, seed: int, split: str, config: OccupancyDataConfig, workers: int = 1, start: int = 0
) -> OccupancySet:
    """Scenes ``start … start + num_scenes − 1`` of the ``(seed, split)`` stream, rendered by ``workers`` processes."""
    chunks = [range(begin, min(begin + 64, start + num_scenes)) for begin in range(start, start + num_scenes, 64)]
    jobs = [(chunk, seed, split, config) for chunk in chunks]
    if workers > 1 and len(jobs) > 1:
        with multiprocessing.get_context("spawn").Pool(min(workers, len(jobs))) as pool:
            parts = pool.map(_generate_chunk, jobs)
    else:
        parts = [_generate_chunk(job) for job in jobs]
    return OccupancySet(*(np.concatenate([part[k] for part in parts]) for k in range(3)))


def cached_occupancy_set(
    cache_dir: Path, num_scenes: int, seed: int, split: str, config: OccupancyDataConfig, workers: int = 1
) -> OccupancySet:
    """:func:`generate_occupancy_set`, stored under ``cache_dir`` keyed by everything that determines it."""
    key = json.dumps({"n": num_scenes, "seed": seed, "split": split, "config": asdict(config)}, sort_keys=True)
    path = Path(cache_dir) / f"occupancy-{split}-{hashlib.sha1(key.encode()).hexdigest()[:12]}.npz"
    if path.is_file():
        return OccupancySet.load(path)
    data = generate_occupancy_set(num_scenes, seed, split, config, workers)
    data.save(path)
    return data


def _generate_chunk(job: tuple[range, int, str, OccupancyDataConfig]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    scenes, seed, split, config = job
    pool = object_ids(split)
    with PointCloudRenderer() as renderer:
        results = [generate_scene(index, seed, pool, renderer, config) for index in scenes]
    return tuple(np.stack([result[k] for result in results]) for k in range(3))
