"""``MetaworldPointCloudEnvConfig``: LeRobot's ``metaworld`` env config with the data contract, registered as
``metaworld_pointcloud``.

``lerobot-eval --env.type=metaworld_pointcloud --env.task=pick-place-v3`` builds ``eval.batch_size`` envs of the
task (``env.MetaworldPointCloudEnv``, a subclass of LeRobot's ``MetaworldEnv``). LeRobot turns the env observations
``pointcloud``, ``agent_pos`` and ``environment_state`` into ``observation.pointcloud (B, P, 3)``,
``observation.state (B, 8)`` and ``observation.environment_state (B, 39)``; the action is ``(8,)``, an absolute EE
target. ``--env.task`` takes a task, a comma-separated list, or a group: ``mt10``, ``mt50`` (every v3 task),
``ml45_train`` / ``ml45_test`` (ML45's split: 45 training tasks, 5 held out) or one of LeRobot's difficulty groups
(``easy``, ``medium``, ``hard``, ``very_hard``); each task is a task group of its own in ``eval_info.json``.

Why a config subclass registered under a new type and not the ``metaworld`` type itself: the subclass keeps
LeRobot's fields and their meaning (``task``, ``fps``, ``episode_length``, the difficulty groups) and builds
LeRobot's env underneath, while the new name leaves ``--env.type=metaworld`` as LeRobot ships it (pixel
observations, 4-D actions) for the policies that read pixels; a type cannot be registered twice.

This module stays light: MetaWorld and MuJoCo are imported only when envs are created, so the base install
(``make demo``) registers the type without the ``metaworld`` extra.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.envs.configs import MetaworldEnv as LeRobotMetaworldConfig

from ...contract import ACTION_KEY, NUM_POINTS, POINTCLOUD_KEY, POSE_GRIPPER_SHAPE, STATE_KEY

ENVIRONMENT_STATE_KEY = "observation.environment_state"
MT10_TASKS = (
    "reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3", "drawer-close-v3",
    "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3", "window-close-v3",
)  # metaworld.env_dict.MT10_V3, written out so that naming tasks needs neither MetaWorld nor an OpenGL library
ML45_TEST_TASKS = ("bin-picking-v3", "box-close-v3", "hand-insert-v3", "door-lock-v3", "door-unlock-v3")
# metaworld.env_dict.ML45_V3["test"]: the tasks ML45 holds out from meta-training, the natural check of a policy
# meant for new tasks; ML45's training tasks are the other 45
LEROBOT_METAWORLD_CONFIG = "metaworld_config.json"  # beside lerobot.envs: its task names and difficulty groups


def make_metaworld_pointcloud_env(task: str, **env_kwargs):
    """One ``MetaworldPointCloudEnv`` (a picklable factory for gymnasium's vector envs). The env module comes first:
    it sets ``MUJOCO_GL`` before anything imports mujoco, also in a fresh worker process."""
    from .env import CameraSettings, MetaworldPointCloudEnv

    cameras = CameraSettings(tuple(env_kwargs.pop("cameras")), env_kwargs.pop("camera_resolution"))
    return MetaworldPointCloudEnv(task, cameras=cameras, **env_kwargs)


def lerobot_metaworld_tasks() -> tuple[list[str], dict[str, list[str]]]:
    """MetaWorld's 50 v3 task names and LeRobot's difficulty groups (``easy`` … ``very_hard``), read from the JSON
    file LeRobot's own MetaWorld env loads (importing that env would import MuJoCo, which needs the GL library)."""
    import json
    from importlib.resources import files

    data = json.loads(files("lerobot.envs").joinpath(LEROBOT_METAWORLD_CONFIG).read_text())
    return list(data["TASK_POLICY_MAPPING"]), dict(data["DIFFICULTY_TO_TASKS"])


def task_groups() -> dict[str, list[str]]:
    """Every task group ``--env.task`` accepts by name: ``mt10``, ``mt50`` (all 50 tasks), ``ml45_train`` and
    ``ml45_test`` (ML45's split) and LeRobot's difficulty groups."""
    all_tasks, difficulty_groups = lerobot_metaworld_tasks()
    return {
        "mt10": list(MT10_TASKS),
        "mt50": all_tasks,
        "ml45_train": [task for task in all_tasks if task not in ML45_TEST_TASKS],
        "ml45_test": list(ML45_TEST_TASKS),
        **difficulty_groups,
    }


def resolve_tasks(task: str) -> list[str]:
    """``task`` → MetaWorld task names: comma-separated task names (the ``metaworld-`` prefix dropped) or groups of
    :func:`task_groups`; unknown names raise ``ValueError`` listing the groups. Imports neither MetaWorld nor MuJoCo."""
    groups = task_groups()
    all_tasks = groups["mt50"]
    names = []
    for item in (part.strip() for part in task.split(",") if part.strip()):
        if item in groups:
            names += groups[item]
            continue
        name = item.removeprefix("metaworld-")
        if name not in all_tasks:
            raise ValueError(f"unknown MetaWorld task {item!r}: give v3 task names (e.g. pick-place-v3) or one of "
                             f"the groups {sorted(groups)}")
        names.append(name)
    if not names:
        raise ValueError("metaworld_pointcloud needs --env.task (a task name or a group: mt10, ml45_test …)")
    return list(dict.fromkeys(names))


@EnvConfig.register_subclass("metaworld_pointcloud")
@dataclass
class MetaworldPointCloudEnvConfig(LeRobotMetaworldConfig):
    """MetaWorld tasks with the data contract's observations and actions (module docstring).

    ``num_points``: points per cloud (the shipped checkpoint's 2048). ``cameras``: MetaWorld camera names the cloud
    is fused from; ``camera_resolution``: their square image size in pixels. ``episode_length``: the step limit
    (MetaWorld's own is 500). ``pointcloud_every``: render the cloud only every this many steps and after gripper
    changes, repeating it in between (``env`` module docstring: 8 renders exactly the steps ``instant_policy`` reads
    with its ``n_action_steps`` of 8; 1, the default, renders every step). ``render_size``: the square size of the
    videos' frames (``render()``; LeRobot's 480), which changes no observation.
    """

    task: str = "pick-place-v3"
    episode_length: int = 200
    num_points: int = NUM_POINTS
    cameras: list[str] = field(default_factory=lambda: ["corner2", "corner", "behindGripper"])
    camera_resolution: int = 320
    pointcloud_every: int = 1
    render_size: int = 480
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=lambda: {
        ACTION_KEY: ACTION_KEY, "agent_pos": STATE_KEY, "pointcloud": POINTCLOUD_KEY,
        "environment_state": ENVIRONMENT_STATE_KEY,
    })

    def __post_init__(self):
        if (self.num_points <= 0 or self.camera_resolution < 2 or not self.cameras or self.pointcloud_every < 1
                or self.render_size < 1):
            raise ValueError("num_points, pointcloud_every and render_size must be positive, camera_resolution at "
                             "least 2 and cameras not empty")
        if not 0 < self.episode_length <= 500:
            raise ValueError(f"episode_length must lie in 1…500 (MetaWorld's limit), got {self.episode_length}")
        self.features = {
            ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=POSE_GRIPPER_SHAPE),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=POSE_GRIPPER_SHAPE),
            "pointcloud": PolicyFeature(type=FeatureType.STATE, shape=(self.num_points, 3)),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(39,)),
        }

    @property
    def gym_kwargs(self) -> dict:
        return {"num_points": self.num_points, "episode_length": self.episode_length, "cameras": list(self.cameras),
                "camera_resolution": self.camera_resolution, "pointcloud_every": self.pointcloud_every,
                "render_size": self.render_size}

    def create_envs(self, n_envs: int, use_async_envs: bool = False):
        """One vector env of ``n_envs`` per task (each its own task group). Asynchronous envs use LeRobot's lazy
        wrapper, as its own MetaWorld env does: a task's worker processes start when that task is evaluated, so
        ``mt10`` keeps ``n_envs`` workers alive, not ten times as many."""
        import gymnasium as gym
        from lerobot.envs.utils import _LazyAsyncVectorEnv, freeze_after_episode_end

        envs, spaces = {}, (None, None, None)
        for task in resolve_tasks(self.task):
            factory = partial(make_metaworld_pointcloud_env, task, **self.gym_kwargs)
            if use_async_envs and n_envs > 1:
                vector_env = _LazyAsyncVectorEnv([factory] * n_envs, *spaces)
                spaces = (vector_env.observation_space, vector_env.action_space, vector_env.metadata)
            else:
                vector_env = gym.vector.SyncVectorEnv([freeze_after_episode_end(factory) for _ in range(n_envs)],
                                                     autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
            envs[task] = {0: vector_env}
        return envs
