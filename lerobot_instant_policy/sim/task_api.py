"""The public task API of ``bullet_tabletop``: define a task, register it by name, pick it with ``--env.task``.

A task says which objects a scene has and how they are randomised (``build``), when the episode is solved
(``is_success``) and how a scripted Cartesian demonstrator solves it (``demonstration``)::

    from lerobot_instant_policy.sim import Part, Task, ScriptedWaypoint, register_task, top_down_pose

    @register_task
    class PushCube(Task):
        name = "push_cube"
        max_episode_steps = 100

        def build(self, scene, rng):
            self.cube = scene.add_box((0.02, 0.02, 0.02), (rng.uniform(0.45, 0.55), 0.0, 0.02))

        def is_success(self, scene):
            return scene.pose(self.cube)[0, 3] > 0.6

        def demonstration(self, scene):
            x, y, _ = scene.pose(self.cube)[:3, 3]
            return [
                ScriptedWaypoint(top_down_pose((x - 0.05, y, 0.15)), gripper_open=False),
                ScriptedWaypoint(top_down_pose((x - 0.05, y, 0.02)), gripper_open=False),
                ScriptedWaypoint(top_down_pose((x + 0.12, y, 0.02)), gripper_open=False),
            ]

``lerobot-eval --env.type=bullet_tabletop --env.task=push_cube --env.task_module=my_package.my_tasks`` imports
the module that registers it (in every env worker process too).
"""

from __future__ import annotations

import abc
import importlib
from typing import ClassVar

import numpy as np

from .demonstrator import ScriptedWaypoint
from .scene import Scene

_REGISTRY: dict[str, type[Task]] = {}


class Task(abc.ABC):
    """A tabletop manipulation task. One instance lives in one env; ``build`` is called at every reset.

    Class attributes: ``name`` (the registry key, also the LeRobot ``task`` string), ``max_episode_steps``
    (the env's step limit at 10 steps per second), ``success_hold_steps`` (how many consecutive steps ``is_success``
    must hold for the env's default ``success="held"`` criterion).
    """

    name: ClassVar[str]
    max_episode_steps: ClassVar[int] = 150
    success_hold_steps: ClassVar[int] = 5

    @abc.abstractmethod
    def build(self, scene: Scene, rng: np.random.Generator) -> None:
        """Create the task's objects in ``scene`` at poses drawn from ``rng`` (yaw within ±60° by convention)."""

    @abc.abstractmethod
    def is_success(self, scene: Scene) -> bool:
        """Whether the task is solved in the scene's current state; never true right after ``build``."""

    @abc.abstractmethod
    def demonstration(self, scene: Scene) -> list[ScriptedWaypoint]:
        """Cartesian EE waypoints (world frame) that solve the task from the scene's state after reset."""


def register_task(task_cls: type[Task] | None = None, *, overwrite: bool = False):
    """Register a ``Task`` subclass under its ``name`` (usable as a decorator, with or without arguments)."""

    def register(cls: type[Task]) -> type[Task]:
        if not (isinstance(cls, type) and issubclass(cls, Task)):
            raise TypeError(f"register_task expects a Task subclass, got {cls!r}")
        name = getattr(cls, "name", None)
        if not isinstance(name, str) or not name:
            raise ValueError(f"{cls.__name__} needs a non-empty class attribute `name`")
        if name in _REGISTRY and _REGISTRY[name] is not cls and not overwrite:
            raise ValueError(f"a task named {name!r} is already registered ({_REGISTRY[name].__name__})")
        _REGISTRY[name] = cls
        return cls

    return register if task_cls is None else register(task_cls)


def _load_builtin_tasks() -> None:
    importlib.import_module("lerobot_instant_policy.sim.tasks")


def task_names() -> list[str]:
    """The names of every registered task (built-in ones included), sorted."""
    _load_builtin_tasks()
    return sorted(_REGISTRY)


def get_task(name: str, task_module: str | None = None) -> type[Task]:
    """The task class registered as ``name``; ``task_module`` is imported first when given.

    Raises:
        ValueError: unknown name; the message lists the known tasks.
    """
    if task_module:
        importlib.import_module(task_module)
    _load_builtin_tasks()
    if name not in _REGISTRY:
        raise ValueError(f"unknown bullet_tabletop task {name!r}; known tasks: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]
