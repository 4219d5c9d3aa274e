"""``BulletTabletopEnv``: a gymnasium env of one ``bullet_tabletop`` task with a Panda driven by EE-pose actions.

Actions ``(8,)``: the absolute EE target pose in the world frame (xyz m, quaternion xyzw) and the gripper
command (≥ 0.5 open, < 0.5 close), docs/design.md §4. A target outside the workspace box is clipped to it
(``info["action_clipped"]``); a target further than ``max_translation_step`` / ``max_rotation_step_deg`` from the
current EE pose is moved toward it by that much (``info["step_clipped"]``); the arm follows through inverse
kinematics over ``physics_substeps`` physics steps of 1/240 s.

Observations (``obs_type="pointcloud"``, the default): ``pointcloud (num_points, 3)`` float32, world frame, the
task objects only (segmentation masks of three depth cameras, fused and farthest-point resampled), and
``agent_pos (8,)`` float32, the EE pose (xyz, quaternion xyzw, w ≥ 0) and the gripper state (1 open, 0 closed;
the last gripper command).

``obs_type="rgbd"`` hands out what a robot with depth cameras has, and no segmentation: ``depth (C, H, W)``
float32 metres along each camera's optical axis (0: no return), ``intrinsics (C, 3, 3)`` and ``T_world_camera
(C, 4, 4)`` (OpenCV camera frame, ``perception.calibration``), ``joint_positions (9,)`` (7 arm joints, 2 fingers,
rad / m) and ``agent_pos``. ``depth_noise_std`` (m) adds Gaussian noise to every return;
``calibration_error_translation`` (m) and ``calibration_error_rotation_deg`` perturb the *reported*
``T_world_camera`` of each camera by exactly that much (random direction and axis, drawn at reset), while the
images are rendered from the true poses.

Success (``info["is_success"]``, which also ends the episode): with ``success="held"`` (the default) the task's goal
state (``Task.is_success``) must hold for the task's ``success_hold_steps`` consecutive control steps (0.5 s at the
default 10 steps per second): a lifted object held up, a block come to rest on its target, a lid that stays open,
not a state passed through. ``success="instant"`` counts the first step in the goal state (a state passed through
counts too). ``info["goal_state"]`` says whether the goal state holds at this step.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from ..contract import NUM_POINTS, POSE_GRIPPER_SHAPE, poses_from_vectors, vectors_from_poses
from ..geometry.sampling import resample_points
from ..geometry.se3 import make_pose, pose_to_pos_quat
from ..objects.rendering import (
    CameraConfig,
    camera_projection_matrix,
    camera_view_matrix,
    default_cameras,
    render_segmented_points,
)
from .demonstrator import interpolate_waypoints
from .robot import PandaRobot, RobotConfig
from .scene import TABLE_CENTRE, TABLE_HALF_EXTENTS, Scene
from .task_api import Task, get_task

PHYSICS_TIMESTEP = 1.0 / 240.0
SUCCESS_CRITERIA = ("held", "instant")  # module docstring
SETTLE_STEPS = 48
_GL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
OBS_TYPES = ("pointcloud", "rgbd")  # segmented clouds from the simulator, or raw depth (module docstring)


@dataclass
class BulletTabletopConfig:
    """Settings of one env (the LeRobot ``EnvConfig`` passes these through)."""

    num_points: int = NUM_POINTS
    fps: int = 10
    max_translation_step: float = 0.02
    max_rotation_step_deg: float = 6.0
    workspace_low: tuple[float, float, float] = (0.15, -0.5, 0.0)
    workspace_high: tuple[float, float, float] = (0.85, 0.5, 0.6)
    max_crop_pixels: int = 64
    render_size: tuple[int, int] = (256, 256)
    episode_length: int | None = None
    cameras: list[CameraConfig] = field(default_factory=default_cameras)
    robot: RobotConfig = field(default_factory=RobotConfig)
    obs_type: str = "pointcloud"
    depth_resolution: tuple[int, int] = (240, 180)
    depth_noise_std: float = 0.0
    calibration_error_translation: float = 0.0
    calibration_error_rotation_deg: float = 0.0
    success: str = "held"

    def __post_init__(self):
        if self.success not in SUCCESS_CRITERIA:
            raise ValueError(f"success must be one of {list(SUCCESS_CRITERIA)}, got {self.success!r}")
        if self.obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {list(OBS_TYPES)}, got {self.obs_type!r}")
        if min(self.depth_resolution) < 2:
            raise ValueError(f"depth_resolution must be at least 2x2 pixels, got {self.depth_resolution}")
        if min(self.depth_noise_std, self.calibration_error_translation, self.calibration_error_rotation_deg) < 0:
            raise ValueError("depth_noise_std and the calibration errors must be non-negative")
        if self.num_points <= 0 or self.fps <= 0 or self.max_crop_pixels < 2:
            raise ValueError("num_points and fps must be positive and max_crop_pixels at least 2")
        if self.max_translation_step <= 0 or self.max_rotation_step_deg <= 0:
            raise ValueError("max_translation_step and max_rotation_step_deg must be positive")
        if np.any(np.asarray(self.workspace_low) >= np.asarray(self.workspace_high)):
            raise ValueError(f"workspace_low {self.workspace_low} must be below workspace_high {self.workspace_high}")
        if self.episode_length is not None and self.episode_length <= 0:
            raise ValueError("episode_length must be positive")
        if round(1.0 / (PHYSICS_TIMESTEP * self.fps)) < 1:
            raise ValueError(f"fps {self.fps} is too high for the physics time step {PHYSICS_TIMESTEP:.4f} s")


class BulletTabletopEnv(gym.Env):
    """One task of the ``bullet_tabletop`` suite (see the module docstring for actions and observations).

    Args:
        task: a registered task name or a ``Task`` instance.
        config: env settings.
        observe_pointcloud: ``False`` skips the cameras (the cloud is zeros); for fast scripted checks only.
        task_module: imported before resolving ``task`` (where user tasks are registered).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        task: str | Task = "pick_and_lift",
        config: BulletTabletopConfig | None = None,
        observe_pointcloud: bool = True,
        task_module: str | None = None,
        render_mode: str = "rgb_array",
    ):
        super().__init__()
        self.config = config or BulletTabletopConfig()
        if isinstance(task, str):
            task = get_task(task, task_module)()
        elif task_module:
            importlib.import_module(task_module)
        if not isinstance(task, Task):
            raise TypeError(f"task must be a task name or a Task instance, got {type(task).__name__}")
        self.task_impl = task
        self.task = task.name
        self.task_description = task.name
        self.render_mode = render_mode
        self.observe_pointcloud = observe_pointcloud
        self.metadata = {**self.metadata, "render_fps": self.config.fps}
        self._max_episode_steps = self.config.episode_length or task.max_episode_steps
        self._substeps = int(round(1.0 / (PHYSICS_TIMESTEP * self.config.fps)))
        self._workspace_low = np.asarray(self.config.workspace_low, dtype=np.float64)
        self._workspace_high = np.asarray(self.config.workspace_high, dtype=np.float64)
        self.observation_space = gym.spaces.Dict(self._observation_spaces())
        self.action_space = gym.spaces.Box(
            low=np.r_[self._workspace_low, -np.ones(4), 0.0].astype(np.float32),
            high=np.r_[self._workspace_high, np.ones(4), 1.0].astype(np.float32),
            dtype=np.float32,
        )
        self._views = [camera_view_matrix(camera) for camera in self.config.cameras]
        self._projections = [camera_projection_matrix(camera) for camera in self.config.cameras]
        self.client = pybullet.connect(pybullet.DIRECT)
        self.robot: PandaRobot | None = None
        self.scene: Scene | None = None
        self._label_of_body = np.full(1, -1, dtype=np.int8)
        self._elapsed_steps = 0
        self._goal_steps = 0  # consecutive steps in the goal state, up to now
        self._success_hold_steps = task.success_hold_steps if self.config.success == "held" else 1
        self._last_cloud = np.zeros((self.config.num_points, 3), dtype=np.float32)
        self._reported_camera_poses = self.camera_poses()

    # --- gymnasium API ---------------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        pybullet.resetSimulation(physicsClientId=self.client)
        pybullet.setGravity(0.0, 0.0, -9.81, physicsClientId=self.client)
        pybullet.setTimeStep(PHYSICS_TIMESTEP, physicsClientId=self.client)
        table = pybullet.createCollisionShape(
            pybullet.GEOM_BOX, halfExtents=TABLE_HALF_EXTENTS, physicsClientId=self.client
        )
        table_visual = pybullet.createVisualShape(
            pybullet.GEOM_BOX,
            halfExtents=TABLE_HALF_EXTENTS,
            rgbaColor=(0.75, 0.7, 0.6, 1),
            physicsClientId=self.client,
        )
        self.table = pybullet.createMultiBody(0, table, table_visual, TABLE_CENTRE, physicsClientId=self.client)
        self.robot = PandaRobot(self.client, self.config.robot)
        self.robot.reset()
        self.scene = Scene(self.client, self.robot)
        self.task_impl.build(self.scene, self.np_random)
        if not self.scene.object_bodies:
            raise RuntimeError(f"task {self.task!r} built no objects")
        bodies = self.scene.object_bodies
        self._label_of_body = np.full(max(bodies) + 2, -1, dtype=np.int8)
        self._label_of_body[bodies] = 0
        for _ in range(SETTLE_STEPS):
            pybullet.stepSimulation(physicsClientId=self.client)
        self._elapsed_steps = 0
        self._goal_steps = 0
        self._last_cloud = np.zeros((self.config.num_points, 3), dtype=np.float32)
        self._reported_camera_poses = self._perturbed_camera_poses()
        observation, cloud_empty = self.observe()
        return observation, {"is_success": False, "pointcloud_empty": cloud_empty}

    def step(self, action):
        if self.scene is None:
            raise RuntimeError("call reset() before step()")
        target, gripper_open = self._validate_action(action)
        target_position = np.clip(target[:3, 3], self._workspace_low, self._workspace_high)
        action_clipped = not np.allclose(target_position, target[:3, 3])
        target[:3, 3] = target_position
        target, step_clipped = self._bounded_step(target)
        position, quat = pose_to_pos_quat(target)
        self.robot.command_gripper(gripper_open)
        self.robot.command_pose(position, quat)
        for _ in range(self._substeps):
            pybullet.stepSimulation(physicsClientId=self.client)
        self._elapsed_steps += 1
        goal_state = bool(self.task_impl.is_success(self.scene))
        self._goal_steps = self._goal_steps + 1 if goal_state else 0
        success = self._goal_steps >= self._success_hold_steps
        truncated = self._elapsed_steps >= self._max_episode_steps and not success
        observation, cloud_empty = self.observe()
        info = {
            "is_success": success,
            "goal_state": goal_state,
            "action_clipped": action_clipped,
            "step_clipped": step_clipped,
            "pointcloud_empty": cloud_empty,
        }
        return observation, float(success), success, truncated, info

    def render(self) -> np.ndarray:
        """An RGB ``(H, W, 3)`` uint8 view of the whole scene, robot included (for videos)."""
        width, height = self.config.render_size
        view = pybullet.computeViewMatrix((1.2, -0.6, 0.7), (0.45, 0.0, 0.1), (0.0, 0.0, 1.0))
        projection = pybullet.computeProjectionMatrixFOV(50.0, width / height, 0.05, 5.0)
        _, _, rgba, _, _ = pybullet.getCameraImage(
            width,
            height,
            viewMatrix=view,
            projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self.client,
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3].copy()

    def close(self) -> None:
        if pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)

    # --- scripted demonstrations -----------------------------------------------------------------------

    def scripted_actions(self) -> np.ndarray:
        """The task's scripted demonstration from the current state as actions ``(S, 8)`` (call after reset)."""
        if self.scene is None:
            raise RuntimeError("call reset() before scripted_actions()")
        waypoints = self.task_impl.demonstration(self.scene)
        return interpolate_waypoints(self.robot.ee_pose(), self.robot.gripper_open, waypoints)

    def camera_intrinsics(self) -> np.ndarray:
        """``(C, 3, 3)``: each depth camera's pinhole matrix at ``depth_resolution`` (OpenCV convention, pixels)."""
        width, height = self.config.depth_resolution
        matrices = []
        for camera in self.config.cameras:
            focal = height / (2.0 * np.tan(np.radians(camera.fov_deg) / 2.0))
            matrices.append([[focal, 0.0, width / 2.0 - 0.5], [0.0, focal, height / 2.0 - 0.5], [0.0, 0.0, 1.0]])
        return np.asarray(matrices)

    def camera_poses(self) -> np.ndarray:
        """``(C, 4, 4)``: each depth camera's true ``T_world_camera`` (OpenCV optical frame: x right, y down, z
        forward)."""
        return np.stack([np.linalg.inv(view) @ _GL_TO_OPENCV for view in self._views])

    def joint_positions(self) -> np.ndarray:
        """``(9,)`` float32: the 7 arm joints (rad) and the 2 finger joints (m)."""
        return self.robot.joint_positions().astype(np.float32)

    def agent_pos(self) -> np.ndarray:
        """The ``(8,)`` float32 state of docs/design.md §4 (EE pose in the world frame, gripper open flag)."""
        return vectors_from_poses(self.robot.ee_pose(), self.robot.gripper_open).astype(np.float32)

    # --- internals -------------------------------------------------------------------------------------

    def _validate_action(self, action) -> tuple[np.ndarray, bool]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != POSE_GRIPPER_SHAPE:
            raise ValueError(
                f"bullet_tabletop action must have shape (8,) (EE xyz, quat xyzw, gripper), got {action.shape}"
            )
        if not np.all(np.isfinite(action)):
            raise ValueError(f"bullet_tabletop action contains NaN or inf: {action.tolist()}")
        try:
            T_world_ee, gripper_open = poses_from_vectors(action)
        except ValueError as error:
            raise ValueError(f"bullet_tabletop action has a zero quaternion: {action[3:7].tolist()}") from error
        return T_world_ee, bool(gripper_open >= 0.5)

    def _bounded_step(self, target: np.ndarray) -> tuple[np.ndarray, bool]:
        """Move from the current EE pose toward ``target`` by at most the configured translation / rotation."""
        current = self.robot.ee_pose()
        delta = target[:3, 3] - current[:3, 3]
        distance = np.linalg.norm(delta)
        relative = Rotation.from_matrix(current[:3, :3].T @ target[:3, :3]).as_rotvec()
        angle = np.linalg.norm(relative)
        max_angle = np.radians(self.config.max_rotation_step_deg)
        clipped = distance > self.config.max_translation_step + 1e-9 or angle > max_angle + 1e-9
        if not clipped:
            return target, False
        position = current[:3, 3] + delta * min(1.0, self.config.max_translation_step / max(distance, 1e-12))
        rotvec = relative * min(1.0, max_angle / max(angle, 1e-12))
        rotation = current[:3, :3] @ Rotation.from_rotvec(rotvec).as_matrix()
        return make_pose(position, rotation), True

    def _observation_spaces(self) -> dict[str, gym.spaces.Box]:
        spaces = {"agent_pos": gym.spaces.Box(-np.inf, np.inf, POSE_GRIPPER_SHAPE, np.float32)}
        if self.config.obs_type == "pointcloud":
            spaces["pointcloud"] = gym.spaces.Box(-np.inf, np.inf, (self.config.num_points, 3), np.float32)
            return spaces
        cameras = len(self.config.cameras)
        width, height = self.config.depth_resolution
        spaces["depth"] = gym.spaces.Box(0.0, np.inf, (cameras, height, width), np.float32)
        spaces["intrinsics"] = gym.spaces.Box(-np.inf, np.inf, (cameras, 3, 3), np.float32)
        spaces["T_world_camera"] = gym.spaces.Box(-np.inf, np.inf, (cameras, 4, 4), np.float32)
        spaces["joint_positions"] = gym.spaces.Box(-np.inf, np.inf, (9,), np.float32)
        return spaces

    def _perturbed_camera_poses(self) -> np.ndarray:
        """``(C, 4, 4)``: each camera's true ``T_world_camera`` moved by the configured calibration error (a
        translation of exactly ``calibration_error_translation`` m and a rotation of exactly
        ``calibration_error_rotation_deg`` about the camera centre, random directions from ``np_random``)."""
        poses = []
        for pose in self.camera_poses():
            direction = self.np_random.normal(size=3)
            axis = self.np_random.normal(size=3)
            pose[:3, 3] += self.config.calibration_error_translation * direction / np.linalg.norm(direction)
            rotvec = np.radians(self.config.calibration_error_rotation_deg) * axis / np.linalg.norm(axis)
            pose[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix() @ pose[:3, :3]
            poses.append(pose)
        return np.stack(poses)

    def _observe_rgbd(self) -> dict[str, np.ndarray]:
        depth = np.stack([self._render_depth(camera, view) for camera, view in zip(self.config.cameras, self._views, strict=True)])
        if self.config.depth_noise_std > 0:
            returns = depth > 0
            depth[returns] += self.np_random.normal(0.0, self.config.depth_noise_std, int(returns.sum()))
            depth = np.maximum(depth, 0.0)
        return {
            "depth": depth.astype(np.float32),
            "intrinsics": self.camera_intrinsics().astype(np.float32),
            "T_world_camera": self._reported_camera_poses.astype(np.float32),
            "joint_positions": self.joint_positions(),
            "agent_pos": self.agent_pos(),
        }

    def _render_depth(self, camera: CameraConfig, view: np.ndarray) -> np.ndarray:
        """Metric depth ``(H, W)`` float64 of one camera's full frame at ``depth_resolution`` (0 at the far plane)."""
        width, height = self.config.depth_resolution
        projection = pybullet.computeProjectionMatrixFOV(camera.fov_deg, width / height, camera.near, camera.far)
        _, _, _, buffer, _ = pybullet.getCameraImage(
            width,
            height,
            viewMatrix=view.T.reshape(-1).tolist(),
            projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK,
            physicsClientId=self.client,
        )
        buffer = np.asarray(buffer, dtype=np.float64).reshape(height, width)
        depth = camera.far * camera.near / (camera.far - (camera.far - camera.near) * buffer)
        return np.where(buffer >= 1.0 - 1e-7, 0.0, depth)

    def observe(self) -> tuple[dict[str, np.ndarray], bool]:
        """The observation of the current state, rendered now, as ``reset`` and ``step`` return it, and whether the
        cameras saw no object point (the previous cloud is then repeated; always False in ``rgbd`` mode).

        Point-cloud mode: ``pointcloud (P, 3)`` world frame (resampled with the env's RNG; the previous cloud without
        rendering while ``observe_pointcloud`` is False) and ``agent_pos (8,)``. ``rgbd`` mode: ``depth (C, H, W)``
        metres, ``intrinsics``, ``T_world_camera``, ``joint_positions`` and ``agent_pos``.
        """
        if self.config.obs_type == "rgbd":
            return self._observe_rgbd(), False
        cloud_empty = False
        if self.observe_pointcloud:
            points = self._render_points()
            if len(points) == 0:
                cloud_empty = True
            else:
                self._last_cloud = resample_points(points, self.config.num_points, self.np_random)
        return {"pointcloud": self._last_cloud.copy(), "agent_pos": self.agent_pos()}, cloud_empty

    def _render_points(self) -> np.ndarray:
        """World-frame points ``(P, 3)`` of the task objects seen by the cameras (P may be 0)."""
        corners = self.scene.object_corners()
        points = [
            render_segmented_points(
                self.client, camera, view, projection, corners, self._label_of_body, self.config.max_crop_pixels
            )[0]
            for camera, view, projection in zip(self.config.cameras, self._views, self._projections, strict=True)
        ]
        return np.concatenate(points).astype(np.float32)
