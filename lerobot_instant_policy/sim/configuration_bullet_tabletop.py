"""``BulletTabletopEnvConfig``: the LeRobot ``EnvConfig`` registered as ``bullet_tabletop``.

``lerobot-eval --env.type=bullet_tabletop --env.task=NAME`` builds ``eval.batch_size`` envs of task ``NAME``.
LeRobot turns the env observation ``agent_pos`` into ``observation.state`` (B, 8) and ``pointcloud`` into
``observation.pointcloud`` (B, 2048, 3); the action feature is (8,): the data contract of :mod:`..contract`. This
module stays light: the simulator is imported only when envs are created.

``--env.obs_type=rgbd`` makes the env hand out depth images, camera parameters and the joint state instead of
the segmented cloud; its env preprocessor (``get_env_processors``) then builds ``observation.pointcloud`` with
the perception steps of ``lerobot_instant_policy.perception`` (no segmentation from the simulator), so the
features a policy sees are the same in both modes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

from lerobot.configs import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from ..contract import ACTION_KEY, NUM_POINTS, POINTCLOUD_KEY, POSE_GRIPPER_SHAPE, STATE_KEY


def make_bullet_tabletop_env(task: str, task_module: str | None, observe_pointcloud: bool = True, **config_kwargs):
    """One ``BulletTabletopEnv`` (a picklable factory for gymnasium's vector envs)."""
    from .env import BulletTabletopConfig, BulletTabletopEnv

    return BulletTabletopEnv(
        task, BulletTabletopConfig(**config_kwargs), observe_pointcloud=observe_pointcloud, task_module=task_module
    )


@EnvConfig.register_subclass("bullet_tabletop")
@dataclass
class BulletTabletopEnvConfig(EnvConfig):
    """A ``bullet_tabletop`` task (``lerobot-ip-record-demos --list-tasks`` lists them).

    ``task_module``: a module to import first, where user tasks are registered (``sim.task_api``).
    ``episode_length``: step limit; ``None`` uses the task's own. ``max_translation_step`` (m) and
    ``max_rotation_step_deg`` bound how far one action moves the EE. ``obs_type``: ``pointcloud`` (segmented by
    the simulator) or ``rgbd`` (depth ``depth_width`` x ``depth_height`` from three cameras, segmented by the
    perception pipeline); ``depth_noise_std`` (m), ``calibration_error_translation`` (m) and
    ``calibration_error_rotation_deg`` degrade the ``rgbd`` observations (``sim.env``). ``success``: ``held`` (the
    goal state must hold for the task's ``success_hold_steps``) or ``instant`` (the first step in the goal state
    counts, even if the state is only passed through).
    """

    task: str | None = "pick_and_lift"
    fps: int = 10
    episode_length: int | None = None
    num_points: int = NUM_POINTS
    task_module: str | None = None
    max_translation_step: float = 0.02
    max_rotation_step_deg: float = 6.0
    render_size: int = 256
    obs_type: str = "pointcloud"
    depth_width: int = 240
    depth_height: int = 180
    depth_noise_std: float = 0.0
    calibration_error_translation: float = 0.0
    calibration_error_rotation_deg: float = 0.0
    success: str = "held"
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(
        default_factory=lambda: {ACTION_KEY: ACTION_KEY, "agent_pos": STATE_KEY, "pointcloud": POINTCLOUD_KEY}
    )

    def __post_init__(self):
        if self.num_points <= 0 or self.render_size <= 0 or self.fps <= 0:
            raise ValueError("num_points, render_size and fps must be positive")
        from .env import OBS_TYPES  # the env module loads pybullet: only when a config is built

        if self.obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {list(OBS_TYPES)}, got {self.obs_type!r}")
        self.features = {
            ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=POSE_GRIPPER_SHAPE),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=POSE_GRIPPER_SHAPE),
            "pointcloud": PolicyFeature(type=FeatureType.STATE, shape=(self.num_points, 3)),
        }

    @property
    def gym_kwargs(self) -> dict:
        return {
            "num_points": self.num_points,
            "fps": self.fps,
            "episode_length": self.episode_length,
            "max_translation_step": self.max_translation_step,
            "max_rotation_step_deg": self.max_rotation_step_deg,
            "render_size": (self.render_size, self.render_size),
            "obs_type": self.obs_type,
            "depth_resolution": (self.depth_width, self.depth_height),
            "depth_noise_std": self.depth_noise_std,
            "calibration_error_translation": self.calibration_error_translation,
            "calibration_error_rotation_deg": self.calibration_error_rotation_deg,
            "success": self.success,
        }

    def get_env_processors(self):
        """Identity in ``pointcloud`` mode; in ``rgbd`` mode the perception pipeline (depth → segmented cloud)."""
        from lerobot.processor import PolicyProcessorPipeline

        if self.obs_type == "pointcloud":
            return PolicyProcessorPipeline(steps=[]), PolicyProcessorPipeline(steps=[])
        from ..perception.pipeline import make_perception_pipeline

        return make_perception_pipeline(rgbd_perception_config(self.num_points)), PolicyProcessorPipeline(steps=[])

    def create_envs(self, n_envs: int, use_async_envs: bool = False):
        import gymnasium as gym
        from lerobot.envs.utils import freeze_after_episode_end

        from .task_api import get_task

        if self.task is None:
            raise ValueError("bullet_tabletop needs --env.task (see `lerobot-ip-record-demos --list-tasks`)")
        get_task(self.task, self.task_module)  # unknown names fail here, listing the known tasks
        factory = partial(make_bullet_tabletop_env, self.task, self.task_module, **self.gym_kwargs)
        env_fns = [freeze_after_episode_end(factory) for _ in range(n_envs)]
        if use_async_envs and n_envs > 1:
            vector_env = gym.vector.AsyncVectorEnv(
                env_fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, context="forkserver"
            )
        else:
            vector_env = gym.vector.SyncVectorEnv(env_fns, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
        return {self.task: {0: vector_env}}


def rgbd_perception_config(num_points: int = NUM_POINTS):
    """The perception settings for ``bullet_tabletop``'s rgbd observations: the env's workspace box (down to just
    below the table top, so that RANSAC sees the table), the Panda removed by its joint state."""
    from ..perception.pipeline import PerceptionConfig
    from .env import BulletTabletopConfig
    from .robot import JOINT_NAMES, low_poly_panda_urdf

    workspace = BulletTabletopConfig()
    return PerceptionConfig(
        num_points=num_points,
        workspace_low=(workspace.workspace_low[0], workspace.workspace_low[1], -0.05),
        workspace_high=tuple(workspace.workspace_high),
        robot_urdf=low_poly_panda_urdf(),
        robot_joint_names=list(JOINT_NAMES),
    )
