"""Speed of the ``bullet_tabletop`` env: steps per second with point-cloud observations, and one render's time."""

from __future__ import annotations

import os
import statistics
import time


def bench_env(task: str = "pick_and_place", steps: int = 60, repeats: int = 3) -> dict:
    """Median env steps/s (IK, physics, three segmentation cameras, FPS to 2048 points) over ``repeats`` runs of
    ``steps`` scripted steps, and the median time of one point-cloud observation render."""
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
