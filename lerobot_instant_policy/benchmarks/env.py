"""Speed of the ``bullet_tabletop`` env: steps per second with point-cloud observations, one observation's time, and
one video frame's time per render size (``lerobot-eval`` renders a video frame after every step of its first 10
episodes)."""

from __future__ import annotations

import os
import statistics
import time


def bench_env(task: str = "pick_and_place", steps: int = 60, repeats: int = 3,
              video_sizes: tuple[int, ...] = (256, 64)) -> dict:
    """Median env steps/s (IK, physics, three segmentation cameras, FPS to 2048 points) over ``repeats`` runs of
    ``steps`` scripted steps, the median time of one point-cloud observation render, and per square video size
    (``--env.render_size``) the median time of one ``render()`` frame of the same scene."""
    from ..sim.env import BulletTabletopEnv

    env = BulletTabletopEnv(task)
    step_rates, render_times, physics_rates = [], [], []
    try:
        for repeat in range(repeats):
            step_rates.append(_scripted_steps_per_s(env, repeat, steps))
            for _ in range(10):
                start = time.perf_counter()
                env.observe()
                render_times.append(time.perf_counter() - start)
        env.observe_pointcloud = False
        physics_rates = [_scripted_steps_per_s(env, repeat, steps) for repeat in range(repeats)]
    finally:
        env.close()
    video_frame_ms = {str(size): round(1000 * _video_frame_s(task, size, steps), 2) for size in video_sizes}
    return {
        "benchmark": "env",
        "task": task,
        "steps_per_run": steps,
        "repeats": repeats,
        "cpu_count": os.cpu_count(),
        "num_points": env.config.num_points,
        "steps_per_s": round(statistics.median(step_rates), 1),
        "observation_render_ms": round(1000 * statistics.median(render_times), 2),
        "steps_per_s_without_pointcloud": round(statistics.median(physics_rates), 1),
        "video_frame_ms": video_frame_ms,
        "runs_steps_per_s": [round(value, 1) for value in step_rates],
        "target_steps_per_s": 30,
        "meets_target": bool(statistics.median(step_rates) >= 30),
    }


def _scripted_steps_per_s(env, seed: int, steps: int) -> float:
    """Steps per second of ``steps`` steps of the task's scripted plan after ``reset(seed)``."""
    env.reset(seed=seed)
    plan = env.scripted_actions()
    start = time.perf_counter()
    for step in range(steps):
        env.step(plan[min(step, len(plan) - 1)])
    return steps / (time.perf_counter() - start)


def _video_frame_s(task: str, size: int, steps: int, frames: int = 10) -> float:
    """Median seconds of one ``size`` × ``size`` ``render()`` after ``steps`` scripted steps from seed 0."""
    from ..sim.env import BulletTabletopConfig, BulletTabletopEnv

    env = BulletTabletopEnv(task, BulletTabletopConfig(render_size=(size, size)), observe_pointcloud=False)
    try:
        _scripted_steps_per_s(env, 0, steps)  # into the same scene as the step benchmark
        times = []
        for _ in range(frames):
            start = time.perf_counter()
            env.render()
            times.append(time.perf_counter() - start)
    finally:
        env.close()
    return statistics.median(times)
