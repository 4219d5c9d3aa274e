"""Running the scripted demonstrator (or a do-nothing policy) through a ``BulletTabletopEnv`` episode."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .env import BulletTabletopEnv


@dataclass
class EpisodeRecord:
    """One episode: ``points (F, P, 3)``, ``state (F, 8)`` (before each action), ``action (F, 8)`` float32.

    ``images``: ``(F, H, W, 3)`` uint8 renders when requested, else ``None``. In ``rgbd`` mode ``points`` is
    ``None`` and ``depth (F, C, H, W)`` float32 metres and ``joint_positions (F, 9)`` hold the raw observations.
    """

    task: str
    seed: int
    success: bool
    points: np.ndarray | None
    state: np.ndarray
    action: np.ndarray
    images: np.ndarray | None = field(default=None)
    depth: np.ndarray | None = field(default=None)
    joint_positions: np.ndarray | None = field(default=None)

    @property
    def num_frames(self) -> int:
        return len(self.state)


def run_episode(
    env: BulletTabletopEnv, seed: int, policy: str = "scripted", with_images: bool = False
) -> EpisodeRecord:
    """Reset ``env`` with ``seed`` and run ``policy`` until success or the step limit.

    ``"scripted"``: the task's demonstration; once its actions are used up the last one is held.
    ``"idle"``: hold the start pose with the gripper open (the do-nothing baseline).
    """
    if policy not in ("scripted", "idle"):
        raise ValueError(f"policy must be 'scripted' or 'idle', got {policy!r}")
    observation, info = env.reset(seed=seed)
    if policy == "scripted":
        plan = env.scripted_actions()
    else:
        plan = observation["agent_pos"][None].astype(np.float64)
    points, states, actions, images, depth, joints = [], [], [], [], [], []
    rgbd = env.config.obs_type == "rgbd"
    success = False
    for step in range(env._max_episode_steps):
        action = plan[min(step, len(plan) - 1)]
        if rgbd:
            depth.append(observation["depth"])
            joints.append(observation["joint_positions"])
        else:
            points.append(observation["pointcloud"])
        states.append(observation["agent_pos"])
        actions.append(action.astype(np.float32))
        if with_images:
            images.append(env.render())
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            success = bool(info["is_success"])
            break
    return EpisodeRecord(
        task=env.task,
        seed=seed,
        success=success,
        points=None if rgbd else np.stack(points),
        state=np.stack(states),
        action=np.stack(actions),
        images=np.stack(images) if with_images else None,
        depth=np.stack(depth) if rgbd else None,
        joint_positions=np.stack(joints) if rgbd else None,
    )
