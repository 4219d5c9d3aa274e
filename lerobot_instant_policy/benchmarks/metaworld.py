"""Speed of LeRobot's MetaWorld env with the data contract (``metaworld_pointcloud``): env steps per second with
point-cloud observations rendered every step and every ``pointcloud_every`` steps, and one cloud's time."""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

TARGET_STEPS_PER_S = 5.0  # docs/design.md §9: MetaWorld with clouds


def bench_metaworld_env(task: str = "pick-place-v3", steps: int = 40, repeats: int = 3,
                        pointcloud_every: int = 8) -> dict:
    """Median steps/s of ``steps`` scripted-expert steps after ``reset(seed)`` over ``repeats`` runs, with the cloud
    rendered every step and every ``pointcloud_every`` steps, and the median time of one cloud (the cameras' depth
    and segmentation passes, back-projection and resampling)."""
    from ..sim.metaworld.env import MetaworldPointCloudEnv

    rates = {}
    cloud_times = []
    for every in (1, pointcloud_every):
        env = MetaworldPointCloudEnv(task, pointcloud_every=every)
        try:
            rates[every] = [_expert_steps_per_s(env, repeat, steps) for repeat in range(repeats)]
            if every == 1:
                rng = np.random.default_rng(0)
                for _ in range(5):
                    start = time.perf_counter()
                    env.cameras.cloud(env.metaworld_env.data, env.num_points, rng)
                    cloud_times.append(time.perf_counter() - start)
                settings = env.camera_settings
        finally:
            env.close()
    every_step, every_k = statistics.median(rates[1]), statistics.median(rates[pointcloud_every])
    return {
        "benchmark": "metaworld-env",
        "task": task,
        "steps_per_run": steps,
        "repeats": repeats,
        "cpu_count": os.cpu_count(),
        "mujoco_gl": os.environ.get("MUJOCO_GL"),
        "cameras": list(settings.cameras),
        "camera_resolution": settings.resolution,
        "cloud_ms": round(1000 * statistics.median(cloud_times), 1),
        "steps_per_s_cloud_every_step": round(every_step, 1),
        "pointcloud_every": pointcloud_every,
        f"steps_per_s_cloud_every_{pointcloud_every}": round(every_k, 1),
        "runs_steps_per_s_cloud_every_step": [round(value, 1) for value in rates[1]],
        "target_steps_per_s": TARGET_STEPS_PER_S,
        "meets_target_cloud_every_step": bool(every_step >= TARGET_STEPS_PER_S),
        f"meets_target_cloud_every_{pointcloud_every}": bool(every_k >= TARGET_STEPS_PER_S),
    }


def _expert_steps_per_s(env, seed: int, steps: int) -> float:
    """Steps per second of ``steps`` steps of the task's scripted expert after ``reset(seed)`` (reset on success)."""
    from ..sim.metaworld.expert import expert_target, scripted_policy

    policy = scripted_policy(env.task)
    observation, _ = env.reset(seed=seed)
    action_scale = env.metaworld_env.action_scale
    start = time.perf_counter()
    for _ in range(steps):
        action = expert_target(policy, observation["environment_state"], observation["agent_pos"], action_scale)
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            observation, _ = env.reset()
    return steps / (time.perf_counter() - start)
