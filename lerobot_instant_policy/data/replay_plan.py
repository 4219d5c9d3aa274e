"""A demonstration replayed in the live scene: the plan of the ``demo_replay`` baseline, and the guess that
``instant_policy`` can start its denoising from (``InstantPolicyConfig.replay_init_strength``).

:func:`plan_replay` registers the first-frame cloud of every demonstration of a task onto the live cloud
(:func:`~..geometry.registration.register_rigid`: principal axes + trimmed ICP), keeps the demonstration that fits
best (lowest ``fit_error``) and moves its actions by the estimated ``T_now_demo``:
``T_world_ee_now = T_now_demo @ T_world_ee_demo`` for every commanded pose, gripper commands unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..contract import poses_from_vectors, vectors_from_poses
from ..geometry.registration import RegistrationConfig, RegistrationResult, register_rigid
from .demonstrations import Demonstration


@dataclass(frozen=True)
class ReplayPlan:
    """The actions one env executes: ``actions (F, 8)`` in the world frame, from demonstration ``demo_index`` of
    ``task`` moved by ``T_now_demo (4, 4)``; ``registration`` is the winning fit."""

    task: str
    demo_index: int
    T_now_demo: np.ndarray
    actions: np.ndarray
    registration: RegistrationResult

    def actions_from(self, step: int, count: int) -> np.ndarray:
        """Planned actions ``step … step + count − 1``, ``(count, 8)``; past the plan's end its last action repeats."""
        indices = np.minimum(np.arange(step, step + count), len(self.actions) - 1)
        return self.actions[indices]


def plan_replay(
    task: str, demonstrations: list[Demonstration], cloud_now: np.ndarray, config: RegistrationConfig
) -> ReplayPlan:
    """Register every demonstration of ``task`` onto ``cloud_now (P, 3)`` (world frame) and plan the best one's
    actions in the live scene."""
    if not demonstrations:
        raise ValueError(f"no demonstrations of task {task!r} to replay")
    fits = [register_rigid(demo.points_world[0], cloud_now, config) for demo in demonstrations]
    best = int(np.argmin([fit.fit_error for fit in fits]))
    T_now_demo = fits[best].T_target_source
    actions = transform_pose_actions(T_now_demo, demonstrations[best].action)
    return ReplayPlan(task=task, demo_index=best, T_now_demo=T_now_demo, actions=actions, registration=fits[best])


def transform_pose_actions(T_now_demo: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Move absolute EE-pose actions ``(F, 8)`` (xyz, quaternion xyzw, gripper) by ``T_now_demo (4, 4)``.

    Each commanded ``T_world_ee`` becomes ``T_now_demo @ T_world_ee``; the gripper command is kept. Quaternions
    come out normalised with ``w >= 0``.
    """
    T_world_ee, gripper_open = poses_from_vectors(actions)
    return vectors_from_poses(T_now_demo @ T_world_ee, gripper_open).astype(np.float32)
