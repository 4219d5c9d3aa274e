"""``bullet_tabletop``: a pybullet tabletop task suite with a Franka Panda, as a LeRobot env.

Importing this package registers the LeRobot ``EnvConfig`` (``bullet_tabletop``) and nothing heavier; the
simulator and the task API load on first use: ``Task``, ``register_task``, ``get_task``, ``task_names``
(``task_api``), ``Scene``/``Part`` (``scene``), ``ScriptedWaypoint``/``top_down_pose``/``approach_pose``/``grasp_yaw``
(``demonstrator``), ``BulletTabletopEnv``/``BulletTabletopConfig`` (``env``), ``run_episode`` (``rollout``).
"""

from __future__ import annotations

import importlib

from .configuration_bullet_tabletop import BulletTabletopEnvConfig
from .metaworld import MetaworldPointCloudEnvConfig  # registers the metaworld_pointcloud env type (light)

_LAZY = {
    "Task": "task_api",
    "register_task": "task_api",
    "get_task": "task_api",
    "task_names": "task_api",
    "Scene": "scene",
    "Part": "scene",
    "ScriptedWaypoint": "demonstrator",
    "top_down_pose": "demonstrator",
    "approach_pose": "demonstrator",
    "grasp_yaw": "demonstrator",
    "BulletTabletopEnv": "env",
    "BulletTabletopConfig": "env",
    "run_episode": "rollout",
    "EpisodeRecord": "rollout",
}

__all__ = ["BulletTabletopEnvConfig", "MetaworldPointCloudEnvConfig", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
