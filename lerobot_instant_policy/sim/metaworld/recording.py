"""MetaWorld's scripted experts recorded as LeRobotDatasets in the data contract (``lerobot-ip-record-demos --env
metaworld``).

Each episode runs the task's scripted expert (:mod:`.expert`) through ``MetaworldPointCloudEnv`` from
``reset(seed)`` until MetaWorld reports success; every frame holds the cloud and the EE state before the step and
the EE target sent (``observation.pointcloud``, ``observation.state``, ``action``), and ``task`` = the task name
(or ``label``). Only successful episodes are written: a failed seed is skipped and the next one tried (at most
``max_attempts`` seeds per episode), as for ``bullet_tabletop`` (``sim.recording``).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

METAWORLD_FPS = 80  # LeRobot's metaworld env config


def record_expert_demos(
    task: str,
    episodes: int,
    out: Path,
    repo_id: str,
    seed: int,
    overwrite: bool = False,
    label: str | None = None,
    max_attempts: int = 5,
    episode_length: int = 200,
) -> dict:
    """Record ``episodes`` successful expert demonstrations of MetaWorld task ``task`` on seeds ``seed``,
    ``seed + 1``, … into a new dataset at ``out``; returns a summary (the seeds used and those that failed)."""
    from ...data.lerobot_format import create_dataset, write_episode
    from .env import MetaworldPointCloudEnv
    from .expert import scripted_policy

    label = task if label is None else label
    policy = scripted_policy(task)
    if out.exists():
        if not overwrite:
            raise FileExistsError(f"{out} already exists; pass --overwrite to replace it")
        shutil.rmtree(out)
    env = MetaworldPointCloudEnv(task, episode_length=episode_length)
    try:
        dataset = create_dataset(repo_id, out, fps=METAWORLD_FPS, num_points=env.num_points)
        recorded, failed, next_seed = [], [], seed
        while len(recorded) < episodes:
            if len(failed) >= max_attempts * episodes:
                raise RuntimeError(f"MetaWorld's scripted expert of {task!r} failed on seeds {failed}")
            points, states, actions, success = _expert_episode(env, policy, next_seed)
            if success:
                write_episode(dataset, points, states, actions, label)
                recorded.append(next_seed)
            else:
                failed.append(next_seed)
            next_seed += 1
        dataset.finalize()
    finally:
        env.close()
    return {"task": task, "label": label, "repo_id": repo_id, "root": str(out), "episodes": len(recorded),
            "seeds": recorded, "failed_seeds": failed}


def _expert_episode(env, policy, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """One episode of the scripted ``policy``: ``points (F, P, 3)``, ``state (F, 8)``, ``action (F, 8)`` and its
    success."""
    from .expert import expert_target

    observation, _ = env.reset(seed=seed)
    action_scale = env.metaworld_env.action_scale
    points, states, actions = [], [], []
    for _ in range(env._max_episode_steps):
        action = expert_target(policy, observation["environment_state"], observation["agent_pos"], action_scale)
        points.append(observation["pointcloud"])
        states.append(observation["agent_pos"])
        actions.append(action)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return np.stack(points), np.stack(states), np.stack(actions), bool(info["is_success"])
    return np.stack(points), np.stack(states), np.stack(actions), False
