"""Splatting settings of the pseudo-task stream against pybullet: per setting (z-buffer size, surface samples per
object), the milliseconds a cloud costs (planning excluded: rendering and resampling to P points, one task per
call, on this CPU) and the mean nearest-neighbour distance, each way, between its clouds and a dense pybullet
rendering of the same scene (crops of up to 320 px), over the context waypoints of the first ``tasks`` tasks.
Chooses how coarse the pool's generators may render before the clouds change."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy.spatial import cKDTree

from lerobot_instant_policy.objects.library import load_object
from lerobot_instant_policy.objects.rendering import PointCloudRenderer, RenderConfig
from lerobot_instant_policy.pseudo_demos.stream import PseudoTaskStream, StreamConfig


def _chamfer_mm(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    return float(cKDTree(b).query(a)[0].mean()) * 1e3, float(cKDTree(a).query(b)[0].mean()) * 1e3


def bench_splat(config: StreamConfig, settings: list[tuple[int, int, int]], tasks: int = 4) -> dict:
    """``settings``: ``(width, height, surface_samples)`` each; ``config``: the stream (its first ``tasks`` tasks)."""
    result = {"tasks": tasks, "settings": {}}
    rendered = {}
    for width, height, samples in settings:
        stream = PseudoTaskStream(dataclasses.replace(config, zbuffer_resolution=(width, height),
                                                      surface_samples=samples, tasks_per_render=1))
        stream.render_tasks([0])  # builds the surface samples of the first task's objects
        clouds, seconds = [], 0.0
        for task in range(tasks):
            planned = stream._plan(task)
            started = time.perf_counter()
            task_clouds = stream._render([planned])[0] if planned is not None else None
            seconds += time.perf_counter() - started
            clouds.append((planned, task_clouds))
        count = sum(len(task_clouds) for _, task_clouds in clouds if task_clouds is not None)
        rendered[(width, height, samples)] = clouds
        result["settings"][f"{width}x{height}/{samples}"] = {"ms_per_cloud": round(1000 * seconds / count, 2)}
    with PointCloudRenderer(RenderConfig(max_crop_pixels=320)) as dense:
        for key, clouds in rendered.items():
            figures = []
            for planned, task_clouds in clouds:
                if task_clouds is None:
                    continue
                dense.set_objects([load_object(object_id) for object_id in planned.planned.task.object_ids])
                for row, (demo_index, frame) in enumerate(
                        (d, f) for d, frames in enumerate(planned.chosen) for f in frames):
                    demo = planned.planned.demos[demo_index]
                    reference, _ = dense.render(list(demo.T_world_objects[frame]),
                                                planned.T_world_ee.reshape(-1, 4, 4)[row].astype(np.float64),
                                                bool(demo.state[frame, 7]))
                    figures.append(_chamfer_mm(task_clouds[row].cpu().numpy(), reference))
            to_dense, from_dense = np.mean(figures, axis=0)
            entry = result["settings"][f"{key[0]}x{key[1]}/{key[2]}"]
            entry.update(splat_to_pybullet_mm=round(float(to_dense), 2), pybullet_to_splat_mm=round(float(from_dense), 2),
                         clouds=len(figures))
    return result
