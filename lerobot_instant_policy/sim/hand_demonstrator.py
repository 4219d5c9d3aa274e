"""A simulated person demonstrating ``bullet_tabletop`` tasks with a hand, recorded as a real hand demonstration is
(``perception.hand_recording``) and converted by the same path (``perception.hand_convert``).

The person follows the task's scripted demonstration (``Task.demonstration``, interpolated as for the robot) with
the articulated hand of ``sim.hand_model``, as a person would: the hand's EE frame follows the scripted EE poses with
*approach jitter* (a smooth random offset of about ``approach_jitter_m`` that fades out within ``JITTER_FADE_M`` of
every waypoint, where the task needs precision), the pinch open to an aperture drawn per demonstration and slowly
varying while open, and closing at ``closing_speed_m_s`` when the script closes the gripper, until both the thumb
and the index touch one object (the fingers close around it and stop there; the little fingers curl with it) or
the tips meet. The robot is parked 5 m below the table, out of every camera's view and reach.

How the hand moves objects: the hand is kinematic (its pose is set at every physics step, interpolated within a
control step) and collides with the objects through the thumb, the index and the palm, so it pushes, presses and
knocks over as the gripper does. A pinch that has closed on an object *carries it by a constraint*: a fixed
pybullet constraint holds the touched link at its pose relative to the palm until the script opens the pinch. This
stands in for friction between soft fingertips and the object, which a kinematic hand cannot produce (an immovable
body's contacts have no grip); the constraint's force is bounded (``carry_force_n``), so articulated objects still
move only along their joints.

Every control step (``fps``) records, before the step: each camera's RGB and depth (millimetres) with its
intrinsics and pose (the env's cameras at ``depth_resolution``), the hand's 21 landmarks in the world frame with
detector-like Gaussian noise (``landmark_noise_m`` per coordinate) and whole frames dropped with probability
``drop_probability`` (NaN), (``record_hand_mask``) the hand's pixels from the cameras' segmentation, where the
hand has its own body id: what a segmenting detector would give, and (``record_object_mask``) the task objects'
pixels from the same segmentation: what a segmenter run on the RGB gives, and how the robot's own demonstrations in
this simulator are segmented. A demonstration ends at its first step in the
task's goal state as a person's does: ``after_goal_frames`` frames after it, still following the script, and when
the hand is letting go there, not before the pinch has been open that many frames. A recording holds no command,
only where the hand was, so one cut at the goal would end a step short of it (a converted episode's last action is
its last state) and never show the release the robot's gripper state shows at once.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet

from ..contract import poses_from_vectors
from ..geometry.se3 import invert, make_pose, pose_to_pos_quat, slerp_rotations
from ..objects.rendering import camera_view_matrix
from ..perception.hand import HandGapError, HandMappingConfig
from ..perception.hand_recording import HandRecording, save_hand_recording
from .env import PHYSICS_TIMESTEP, BulletTabletopConfig, BulletTabletopEnv
from .hand_model import MAX_APERTURE, MIN_APERTURE, SimulatedHand

DEMONSTRATORS = ("gripper", "hand")  # who demonstrates: the scripted robot gripper, or the simulated person's hand
JITTER_FADE_M = 0.08
AFTER_GOAL_STEPS_MAX = 10  # control steps a demonstration may go on past the task's limit after its goal
PINCH_INNER_MARGIN_M = 0.004  # a contact counts as a pinch this far inside the tips (half a fingertip's radius)
PARKED_ROBOT_POSITION = (0.0, 0.0, -5.0)
# The mapping for this hand: the thumb and index tip landmarks sit a capsule radius inside the fingertips, so a pinch
# on the suite's 4 cm blocks reads about 5.7 cm, a thin handle 3.7 cm, touching tips 1.8 cm; an open hand 8.5-11.5 cm.
# The band between the thresholds sits between the two, 2 debounce frames (workbench.hand_window).
SIM_HAND_MAPPING = HandMappingConfig(close_below_m=0.07, open_above_m=0.083, gripper_hold_frames=2)


@dataclass(frozen=True)
class HandDemonstratorConfig:
    """How the simulated person demonstrates (module docstring; metres, seconds)."""

    landmark_noise_m: float = 0.01
    drop_probability: float = 0.05
    approach_jitter_m: float = 0.01
    open_aperture_m: tuple[float, float] = (0.09, 0.11)
    aperture_wobble_m: float = 0.005
    closing_speed_m_s: float = 0.15
    carry_force_n: float = 200.0
    after_goal_frames: int = 3
    record_hand_mask: bool = True
    record_object_mask: bool = True

    def __post_init__(self):
        if min(self.landmark_noise_m, self.approach_jitter_m, self.aperture_wobble_m) < 0:
            raise ValueError("landmark_noise_m, approach_jitter_m and aperture_wobble_m must be non-negative")
        if not 0.0 <= self.drop_probability < 1.0:
            raise ValueError(f"drop_probability must be in [0, 1), got {self.drop_probability}")
        low, high = self.open_aperture_m
        if not SIM_HAND_MAPPING.open_above_m < low - self.aperture_wobble_m <= high + self.aperture_wobble_m \
                <= MAX_APERTURE:
            raise ValueError(f"open_aperture_m ± aperture_wobble_m must lie in ({SIM_HAND_MAPPING.open_above_m}, "
                             f"{MAX_APERTURE}] m, got {self.open_aperture_m} ± {self.aperture_wobble_m}")
        if self.closing_speed_m_s <= 0 or self.carry_force_n <= 0:
            raise ValueError("closing_speed_m_s and carry_force_n must be positive")
        if self.after_goal_frames < 0:
            raise ValueError(f"after_goal_frames must be non-negative, got {self.after_goal_frames}")


@dataclass(frozen=True)
class HandDemonstration:
    """One demonstration by the simulated hand: its ``recording`` (``perception.hand_recording``, world landmarks
    with the configured noise), whether it reached the goal (``success``), its ``seed``, and per recorded frame the
    hand's true EE frame ``T_world_ee (T, 4, 4)``, thumb-index ``aperture (T,)`` m, and ``pinch_open (T,)`` bool: the
    script's gripper command the hand follows from that frame (what the robot's gripper does in its demonstration)."""

    recording: HandRecording
    success: bool
    seed: int
    T_world_ee: np.ndarray
    aperture: np.ndarray
    pinch_open: np.ndarray


def hand_path(plan: np.ndarray, T_world_start: np.ndarray, waypoints: np.ndarray, jitter_m: float,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The hand's EE targets ``T_world_ee (S, 4, 4)`` and pinch commands ``gripper_open (S,)`` bool for the scripted
    ``plan (S, 8)`` (from ``T_world_start (4, 4)``), its positions moved by the approach jitter (module docstring;
    ``waypoints (W, 3)``: the scripted waypoints' positions, where the jitter fades out)."""
    T_world_ee, gripper = poses_from_vectors(plan)
    if jitter_m > 0:
        noise = rng.normal(0.0, 1.0, (len(plan) + 16, 3))
        smooth = np.stack([np.convolve(noise[:, axis], np.hanning(9), mode="same") for axis in range(3)], axis=1)
        smooth = smooth[8:8 + len(plan)] * jitter_m / max(smooth.std(), 1e-9)
        distance = np.linalg.norm(T_world_ee[:, None, :3, 3] - waypoints[None], axis=-1).min(axis=1)
        distance = np.minimum(distance, np.linalg.norm(T_world_ee[:, :3, 3] - T_world_start[:3, 3], axis=-1))
        T_world_ee[:, :3, 3] += np.clip(distance / JITTER_FADE_M, 0.0, 1.0)[:, None] * smooth
    return T_world_ee, gripper >= 0.5


class _Carry:
    """An object link held at its pose relative to the palm by a fixed constraint (module docstring)."""

    def __init__(self, client: int, body: int, link: int, T_world_palm: np.ndarray, force: float):
        self.client, self.force = client, force
        if link < 0:
            position, quat = pybullet.getBasePositionAndOrientation(body, physicsClientId=client)
        else:
            position, quat = pybullet.getLinkState(body, link, physicsClientId=client)[:2]
        T_world_link = make_pose(np.asarray(position), np.asarray(pybullet.getMatrixFromQuaternion(quat)).reshape(3, 3))
        self.T_palm_link = invert(T_world_palm) @ T_world_link
        self.constraint = pybullet.createConstraint(
            body, link, -1, -1, pybullet.JOINT_FIXED, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), position,
            childFrameOrientation=quat, physicsClientId=client,
        )
        pybullet.changeConstraint(self.constraint, maxForce=force, physicsClientId=client)

    def follow(self, T_world_palm: np.ndarray) -> None:
        position, quat = pose_to_pos_quat(T_world_palm @ self.T_palm_link)
        pybullet.changeConstraint(self.constraint, position.tolist(), quat.tolist(), maxForce=self.force,
                                  physicsClientId=self.client)

    def release(self) -> None:
        pybullet.removeConstraint(self.constraint, physicsClientId=self.client)


def _pinched_link(env: BulletTabletopEnv, hand: SimulatedHand, T_world_ee: np.ndarray) -> tuple[int, int] | None:
    """``(body, link)`` of the task object that both the thumb and the index touch (within 1 mm) on their inner
    sides, between the tips (``T_world_ee (4, 4)``: the hand's EE frame), else ``None``: tips resting on a surface
    under them do not grasp it."""
    T_ee_world = invert(T_world_ee)
    inner = hand.aperture / 2 - PINCH_INNER_MARGIN_M
    for body in env.scene.object_bodies:
        touched = []
        for link in hand.pinch_links:
            points = pybullet.getClosestPoints(hand.body, body, 0.001, linkIndexA=link, physicsClientId=env.client)
            touched.append({point[4] for point in points
                            if abs((T_ee_world[:3, :3] @ np.asarray(point[6]) + T_ee_world[:3, 3])[1]) < inner})
        if touched[0] and touched[1]:
            return body, min(touched[1])
    return None


def _render(env: BulletTabletopEnv, views: list[np.ndarray], hand_body: int) -> tuple[np.ndarray, ...]:
    """Every camera's ``rgb (C, H, W, 3)`` uint8, ``depth (C, H, W)`` m (0: no return), ``hand (C, H, W)`` bool
    and ``objects (C, H, W)`` bool (the task objects' pixels)."""
    width, height = env.config.depth_resolution
    rgbs, depths, hands, objects = [], [], [], []
    for camera, view in zip(env.config.cameras, views, strict=True):
        projection = pybullet.computeProjectionMatrixFOV(camera.fov_deg, width / height, camera.near, camera.far)
        _, _, rgba, buffer, segmentation = pybullet.getCameraImage(
            width, height, viewMatrix=view.T.reshape(-1).tolist(), projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER, physicsClientId=env.client,
        )
        buffer = np.asarray(buffer, dtype=np.float64).reshape(height, width)
        depth = camera.far * camera.near / (camera.far - (camera.far - camera.near) * buffer)
        depths.append(np.where(buffer >= 1.0 - 1e-7, 0.0, depth))
        rgbs.append(np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3])
        segmentation = np.asarray(segmentation).reshape(height, width)
        hands.append(segmentation == hand_body)
        objects.append(np.isin(segmentation, env.scene.object_bodies))
    return np.stack(rgbs), np.stack(depths), np.stack(hands), np.stack(objects)


def perform_hand_demonstration(env: BulletTabletopEnv, seed: int, config: HandDemonstratorConfig | None = None,
                               label: str | None = None) -> HandDemonstration:
    """Reset ``env`` with ``seed`` and demonstrate its task with the simulated hand (module docstring); the person's
    randomness (jitter, apertures, noise, drops) is drawn from ``seed`` too. ``label``: the recording's task string
    (default the task's name)."""
    config = config or HandDemonstratorConfig()
    rng = np.random.default_rng([seed, 62])
    env.reset(seed=seed)
    T_world_start = env.robot.ee_pose()
    plan = env.scripted_actions()
    waypoints = np.stack([waypoint.T_world_ee[:3, 3] for waypoint in env.task_impl.demonstration(env.scene)])
    targets, pinch_open = hand_path(plan, T_world_start, waypoints, config.approach_jitter_m, rng)
    pybullet.resetBasePositionAndOrientation(env.robot.body, PARKED_ROBOT_POSITION, (0.0, 0.0, 0.0, 1.0),
                                             physicsClientId=env.client)
    hand = SimulatedHand(env.client)
    open_aperture = rng.uniform(*config.open_aperture_m)
    wobble_phase, wobble_period = rng.uniform(0, 2 * np.pi), rng.uniform(2.0, 4.0)
    substeps = int(round(1.0 / (PHYSICS_TIMESTEP * env.config.fps)))
    aperture_step = config.closing_speed_m_s * PHYSICS_TIMESTEP
    views = [camera_view_matrix(camera) for camera in env.config.cameras]
    T_hand, aperture, carry = T_world_start, open_aperture, None
    hand.set_pose(T_hand, aperture)
    frames = dict(rgb=[], depth=[], hand_mask=[], object_mask=[], landmarks=[], T_world_ee=[], aperture=[],
                  pinch_open=[])
    success, frames_open, frames_after_goal = False, 0, 0
    for step in range(env.task_impl.max_episode_steps + AFTER_GOAL_STEPS_MAX):
        rgb, depth, hand_mask, object_mask = _render(env, views, hand.body)
        for key, value in (("rgb", rgb), ("depth", depth), ("hand_mask", hand_mask), ("object_mask", object_mask),
                           ("landmarks", hand.landmarks()), ("T_world_ee", T_hand), ("aperture", hand.aperture)):
            frames[key].append(value)
        target, close = targets[min(step, len(targets) - 1)], not pinch_open[min(step, len(targets) - 1)]
        frames["pinch_open"].append(not close)
        rotations = slerp_rotations(T_hand[:3, :3], target[:3, :3], np.arange(1, substeps + 1) / substeps)
        wanted = open_aperture + config.aperture_wobble_m * np.sin(2 * np.pi * step / (wobble_period * env.config.fps)
                                                                   + wobble_phase)
        for substep in range(substeps):
            fraction = (substep + 1) / substeps
            T_substep = make_pose((1 - fraction) * T_hand[:3, 3] + fraction * target[:3, 3], rotations[substep])
            closing = close and carry is None and aperture > MIN_APERTURE
            if not close:
                if carry is not None:
                    carry.release()
                    carry = None
                aperture = min(aperture + aperture_step, wanted)
            elif closing:
                aperture = max(aperture - aperture_step, MIN_APERTURE)
            hand.set_pose(T_substep, aperture)
            if closing and aperture > MIN_APERTURE:  # a pinch closing on an object grasps it; a closed one pushes
                pinched = _pinched_link(env, hand, T_substep)
                if pinched is not None:
                    carry = _Carry(env.client, *pinched, T_substep, config.carry_force_n)
            if carry is not None:
                carry.follow(T_substep)
            pybullet.stepSimulation(physicsClientId=env.client)
        T_hand = make_pose(target[:3, 3], target[:3, :3])
        frames_open = frames_open + 1 if not close and aperture >= wanted else 0
        success = success or env.task_impl.is_success(env.scene)
        frames_after_goal += success
        let_go = close or frames_open > config.after_goal_frames or frames_open == step + 1
        if frames_after_goal > config.after_goal_frames and let_go or not success and \
                step + 1 >= env.task_impl.max_episode_steps:
            break
    landmarks = np.stack(frames["landmarks"])
    landmarks = landmarks + rng.normal(0.0, config.landmark_noise_m, landmarks.shape)
    landmarks[rng.random(len(landmarks)) < config.drop_probability] = np.nan
    frame_count = len(landmarks)
    recording = HandRecording(
        task=label or env.task, fps=env.config.fps, rgb=np.stack(frames["rgb"]),
        depth=np.round(np.stack(frames["depth"]) * 1000.0).clip(0, np.iinfo(np.uint16).max).astype(np.uint16),
        intrinsics=np.broadcast_to(env.camera_intrinsics(), (frame_count, *env.camera_intrinsics().shape)),
        T_world_camera=np.broadcast_to(env.camera_poses(), (frame_count, *env.camera_poses().shape)),
        landmarks="world", depth_unit="mm", landmarks_world=landmarks,
        hand_mask=np.stack(frames["hand_mask"]) if config.record_hand_mask else None,
        object_mask=np.stack(frames["object_mask"]) if config.record_object_mask else None,
        name=f"{env.task} seed {seed} (simulated hand)",
    )
    return HandDemonstration(recording, success, seed, np.stack(frames["T_world_ee"]), np.array(frames["aperture"]),
                             np.array(frames["pinch_open"]))


def record_hand_demonstrations(
    task: str,
    episodes: int,
    out: Path,
    repo_id: str,
    seed: int,
    config: HandDemonstratorConfig | None = None,
    overwrite: bool = False,
    task_module: str | None = None,
    max_attempts: int = 5,
    label: str | None = None,
    env_config: BulletTabletopConfig | None = None,
) -> dict:
    """Record ``episodes`` successful hand demonstrations of ``task`` (seeds ``seed``, ``seed + 1``, …) as hand
    recordings in ``OUT-recordings/episode_XXX`` and convert them into the dataset ``out`` (``repo_id``) with
    ``perception.hand_convert`` and :data:`SIM_HAND_MAPPING`. A seed fails when the demonstration misses the goal or
    its landmarks have a gap the mapping refuses (too many frames dropped in a row); the next is tried, at most
    ``max_attempts`` per episode. ``label``: the task string written (default ``task``; the context-swap control's)."""
    from ..perception.hand_convert import HandConvertSettings, convert_hand_recordings, map_recording

    recordings_root = out.with_name(out.name + "-recordings")
    for path in (out, recordings_root):
        if path.exists():
            if not overwrite:
                raise FileExistsError(f"{path} already exists; pass --overwrite to replace it")
            shutil.rmtree(path)
    env_config = env_config or BulletTabletopConfig(obs_type="rgbd", success="instant")
    env = BulletTabletopEnv(task, env_config, task_module=task_module)
    # the hand mask is the cameras' own segmentation, exact to the pixel: nothing to grow as for a detector's
    settings = HandConvertSettings(recordings_root, out, repo_id, mapping=SIM_HAND_MAPPING,
                                   num_points=env.config.num_points, hand_mask_dilate_px=0, overwrite=overwrite)
    recorded, failed, next_seed = [], [], seed
    try:
        while len(recorded) < episodes:
            if len(failed) >= max_attempts * episodes:
                raise RuntimeError(f"the simulated hand failed {task!r} on seeds {failed}")
            demonstration = perform_hand_demonstration(env, next_seed, config, label=label or task)
            try:
                map_recording(demonstration.recording, settings)
                usable = demonstration.success
            except HandGapError:
                usable = False
            if usable:
                save_hand_recording(demonstration.recording, recordings_root / f"episode_{len(recorded):03d}")
                recorded.append(next_seed)
            else:
                failed.append(next_seed)
            next_seed += 1
    finally:
        env.close()
    summary = convert_hand_recordings(settings)
    return {"task": task, "label": label or task, "repo_id": repo_id, "root": str(out),
            "recordings": str(recordings_root), "episodes": len(recorded), "seeds": recorded, "failed_seeds": failed,
            "bridged_frames": summary["bridged_frames"], "demonstrator": "hand"}
