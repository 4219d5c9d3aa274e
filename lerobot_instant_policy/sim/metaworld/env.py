"""``MetaworldPointCloudEnv``: LeRobot's own ``MetaworldEnv`` with the data contract's observations and actions.

It subclasses ``lerobot.envs.metaworld.MetaworldEnv`` (LeRobot builds the MetaWorld task, seeds its resets, reports
``info["is_success"]`` from MetaWorld's ``info["success"]`` and renders the RGB frames of LeRobot's videos) and
changes what goes in and out:

* observation ``pointcloud (num_points, 3)`` float32, world frame: the task objects and the task's goal markers
  seen by MuJoCo depth + segmentation cameras (:mod:`.cameras`); ``agent_pos (8,)`` float32: the EE pose and the
  gripper state (the last gripper command, 1 open, 0 closed; open at reset), :mod:`.actions`; ``environment_state
  (39,)`` float32: MetaWorld's own state vector (hand, fingers, object poses, goal), privileged, read only by the
  scripted expert (``metaworld_expert``). The 480x480 RGB frame LeRobot's env renders for its ``pixels``
  observation is not rendered; ``render()`` still draws it for the videos, without shadows and multisampling
  (osmesa draws MetaWorld's 4096² shadow map and 4x multisampling in software: 203 ms a frame here, 32 ms without),
  at ``render_size`` (480, LeRobot's; the suite's commands draw 64: a fifth of an episode's time instead of most).
* action ``(8,)``: the absolute EE target of the data contract, mapped to MetaWorld's 4-D action (:mod:`.actions`;
  ``info["metaworld_action"]`` is the 4-D action sent).
* ``task_description`` is the task name (``pick-place-v3``): policies find their demonstrations by it.
* episodes end at ``episode_length`` steps (MetaWorld's limit is 500) or at MetaWorld's success.

Rendering only where a policy looks: with ``pointcloud_every = k`` the cloud is rendered at reset, after every k-th
step since the last rendering and after every step whose gripper command differs from the one before; otherwise
the observation repeats the last cloud (``info["pointcloud_rendered"]`` says which). These are exactly the steps at
which ``instant_policy`` reads an observation when k is its ``n_action_steps`` (it runs k queued actions, and
predicts again after an action that changes the gripper command); ``demo_replay`` reads the first only, and
``do_nothing`` and ``metaworld_expert`` never read the cloud. ``k = 1`` (the default) renders every step.
A rendering in which no camera sees a task object or goal marker (the hand over all of them, say) keeps the last
cloud, as a camera that loses sight of the scene leaves a policy its last view (``info["pointcloud_rendered"]`` is
then false); at reset, with no view yet, it raises :class:`~.cameras.EmptyCloudError`.

Goals: MetaWorld hides the goal of ``reach``, ``push``, ``pick-place`` … from a camera-only policy unless it is
drawn; the cloud keeps the task's target sites (the spheres MetaWorld draws at ``_target_site_config``), so every
goal is a small marker object in the cloud and moves with MetaWorld's randomisation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from gymnasium import spaces

from .dependencies import import_metaworld

import_metaworld()  # sets MUJOCO_GL and checks the extra before mujoco is imported

import mujoco  # noqa: E402
from lerobot.envs.metaworld import MetaworldEnv  # noqa: E402

from ...contract import NUM_POINTS, POSE_GRIPPER_SHAPE  # noqa: E402
from . import actions  # noqa: E402
from .cameras import CameraSettings, EmptyCloudError, SegmentedDepthCameras  # noqa: E402
from .scenery import task_object_geoms  # noqa: E402

ENVIRONMENT_STATE_SHAPE = (39,)
VIDEO_CAMERA = "corner2"  # LeRobot's camera for MetaWorld, moved by LeRobot to face the table


class MetaworldPointCloudEnv(MetaworldEnv):
    """One MetaWorld v3 task (``reach-v3`` …) with point-cloud observations and EE-target actions (module docstring).

    Args:
        task: a MetaWorld v3 task name (``metaworld-`` prefix allowed).
        num_points: points per cloud.
        episode_length: step limit, at most MetaWorld's 500.
        cameras: the cameras and resolution of the cloud.
        pointcloud_every: render the cloud every this many steps, and after gripper changes (module docstring).
        render_size: the square size of ``render()``'s frames (the videos'; no observation reads them).
    """

    def __init__(self, task: str, num_points: int = NUM_POINTS, episode_length: int = 200,
                 cameras: CameraSettings | None = None, pointcloud_every: int = 1, render_size: int = 480):
        super().__init__(task=task, camera_name=VIDEO_CAMERA, obs_type="pixels", render_mode="rgb_array")
        if render_size < 1:
            raise ValueError(f"render_size must be positive, got {render_size}")
        if not 0 < episode_length <= 500:
            raise ValueError(f"episode_length must lie in 1…500 (MetaWorld's limit), got {episode_length}")
        if pointcloud_every < 1:
            raise ValueError(f"pointcloud_every must be at least 1, got {pointcloud_every}")
        self.num_points = num_points
        self.pointcloud_every = pointcloud_every
        self.render_size = render_size
        self._cloud: np.ndarray | None = None  # the last rendered cloud (None: render at the next observation)
        self._cloud_due = False
        self._cloud_hidden = False  # the last rendering saw no task object, so the cloud before it was kept
        self._steps_since_cloud = 0
        self.camera_settings = cameras or CameraSettings()
        self.task_description = self.task
        self._max_episode_steps = episode_length
        self.cameras: SegmentedDepthCameras | None = None  # the cloud's cameras, built with the MetaWorld env
        self._gripper_open = True
        self._cloud_rng = np.random.default_rng(0)
        pose = spaces.Box(-np.inf, np.inf, shape=POSE_GRIPPER_SHAPE, dtype=np.float32)
        self.observation_space = spaces.Dict({
            "pointcloud": spaces.Box(-np.inf, np.inf, shape=(num_points, 3), dtype=np.float32),
            "agent_pos": pose,
            "environment_state": spaces.Box(-np.inf, np.inf, shape=ENVIRONMENT_STATE_SHAPE, dtype=np.float32),
        })
        self.action_space = spaces.Box(-np.inf, np.inf, shape=POSE_GRIPPER_SHAPE, dtype=np.float32)

    @property
    def metaworld_env(self):
        """The MetaWorld ``SawyerXYZEnv`` underneath (built on first use)."""
        self._ensure_env()
        return self._env

    def _ensure_env(self) -> None:
        if self._env is not None:
            return
        super()._ensure_env()
        self._env.model.light_castshadow[:] = 0  # videos without shadows and multisampling (module docstring);
        self._env.model.vis.quality.offsamples = 0  # read when a renderer's context is made: before any rendering
        self._env.mujoco_renderer.width = self._env.mujoco_renderer.height = self.render_size  # likewise
        target_sites = tuple(name for name, _ in self._env._target_site_config)
        task_geoms = task_object_geoms(self._env.model, Path(self._env.model_name))
        self.cameras = SegmentedDepthCameras(self._env.model, self.camera_settings, task_geoms, target_sites)

    def ee_state(self) -> np.ndarray:
        """``agent_pos (8,)``: the EE pose now (``tcp_center``, hand orientation) and the gripper state."""
        env = self.metaworld_env
        return actions.ee_state(env.data.body("hand").xmat, env.tcp_center, self._gripper_open)

    def reset(self, seed: int | None = None, **kwargs):
        self._gripper_open = True
        self._cloud = None
        if seed is not None:
            self._cloud_rng = np.random.default_rng(seed)
        return super().reset(seed=seed, **kwargs)

    def step(self, action: np.ndarray):
        env = self.metaworld_env
        command = actions.metaworld_action(action, env.tcp_center, env.action_scale)
        gripper_open = bool(np.asarray(action)[7] >= 0.5)
        self._cloud_due = gripper_open != self._gripper_open or self._steps_since_cloud + 1 >= self.pointcloud_every
        self._gripper_open = gripper_open
        rendered = self._cloud_due
        observation, reward, terminated, truncated, info = super().step(command)
        truncated = truncated or (not terminated and env.curr_path_length >= self._max_episode_steps)
        info["metaworld_action"] = command
        info["pointcloud_rendered"] = rendered and not self._cloud_hidden
        return observation, reward, terminated, truncated, info

    def _format_raw_obs(self, raw_obs: np.ndarray) -> dict[str, np.ndarray]:
        if self._cloud is None:
            raw_obs = self._settled_reset_state()
        # MetaWorld places its goal sites after every step but not at reset, where they stay at the last episode's
        # goals until the first step: place them as its step does before the cameras draw them.
        for site, position in self._env._target_site_config:
            self._env._set_pos_site(site, position)
        self._cloud_hidden = False
        if self._cloud is None or self._cloud_due:
            try:
                self._cloud = self.cameras.cloud(self._env.data, self.num_points, self._cloud_rng)
            except EmptyCloudError:
                if self._cloud is None:
                    raise
                self._cloud_hidden = True  # every object out of sight: the last cloud stands (module docstring)
            self._steps_since_cloud = 0
        else:
            self._steps_since_cloud += 1
        self._cloud_due = False
        return {
            "pointcloud": self._cloud.copy(),
            "agent_pos": self.ee_state(),
            "environment_state": np.asarray(raw_obs, dtype=np.float32),
        }

    def _settled_reset_state(self) -> np.ndarray:
        """MetaWorld's state vector ``(39,)`` at reset, after the poses of every body are computed from the model.

        MetaWorld's reset draws the layout twice (``reset_model`` runs in its ``reset`` and again in gymnasium's),
        simulating the hand's return in between, and places some bodies through the model (``model.body(...).pos``:
        peg-insert-side's box, the windows, the drawers, button-press-topdown's box) after that simulation without
        recomputing their world poses. Until the first step those bodies' ``xpos`` are the first draw's, up to 17 cm
        from where the physics then puts them, so the first cloud and the state vector would show them there. One
        ``mj_forward`` computes the poses of the layout in force; the state vector is read again with MetaWorld's
        reset convention (the previous-frame half equal to the current one)."""
        env = self._env
        mujoco.mj_forward(env.model, env.data)
        env._prev_obs = env._get_curr_obs_combined_no_goal()
        return env._get_obs()

    def close(self) -> None:
        if self.cameras is not None:
            self.cameras.close()
            self.cameras = None
        super().close()
