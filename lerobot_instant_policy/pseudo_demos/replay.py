"""Replaying a pseudo-task as pseudo-demonstrations: planned, then rendered.

Each demonstration puts the task's two objects at new poses and the gripper at a new start pose, moves the
gripper through the task's waypoints (fixed in the objects' initial frames), attaches the nearest object
within reach when the gripper closes and releases it when it opens. :func:`plan_demo` does all of that and every
check of a scene, rendering nothing (a :class:`DemoPlan`); :func:`render_demo` then renders a segmented cloud per
frame with pybullet, or :func:`splat_demo` by z-buffer splatting (``objects/splatting.py``). The pseudo-task stream
(``stream.py``) splats the same plans with the same inputs (:func:`splat_inputs`), only at the frames it needs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..contract import vectors_from_poses
from ..geometry.sampling import resample_indices
from ..geometry.se3 import invert, look_rotation, make_pose, transform_points
from ..objects.library import ObjectModel
from ..objects.rendering import CameraConfig, PointCloudRenderer, camera_projection_matrix, camera_view_matrix
from ..objects.splatting import SplatRenderer, library_surface_samples, resample_visible
from .tasks import GRASP_REACH, PseudoTask, Waypoint
from .trajectory import (
    Step,
    add_disturbance,
    add_gripper_faults,
    interpolate_cubic,
    interpolate_linear,
    interpolate_spherical,
    resample_uniform,
    steps_from_states,
)


class GenerationError(RuntimeError):
    """A pseudo-demonstration could not be made (e.g. every resampled scene left the cameras' view)."""


@dataclass
class DemoConfig:
    """How one pseudo-demonstration is laid out, moved, augmented and observed. ``shared_layout_fraction``: the
    probability that a task is one-layout, i.e. every demonstration of it places the objects where its first one
    does and only the gripper's start pose (and the augmentations) differ: the easiest context, where a demonstration
    shows the live scene itself. Otherwise (the paper's setting) every demonstration draws its own object poses;
    ``layout_shift`` in [0, 1] says how far: each later demonstration places every object at its pose in the task's
    first demonstration moved by this fraction of the way (position and yaw) towards a freshly drawn layout
    (:func:`shift_layout`), so 1 (the default, the paper's) is an independent draw and values below 1 give a
    curriculum from the live layout to the paper's setting."""

    num_points: int = 2048
    object_x_range: tuple[float, float] = (0.38, 0.62)
    object_y_range: tuple[float, float] = (-0.22, 0.22)
    object_clearance: float = 0.02
    start_x_range: tuple[float, float] = (0.3, 0.6)
    start_y_range: tuple[float, float] = (-0.25, 0.25)
    start_z_range: tuple[float, float] = (0.22, 0.4)
    start_max_tilt_deg: float = 25.0
    start_max_roll_deg: float = 90.0
    object_max_yaw_deg: float = 180.0
    disturbance_probability: float = 0.3
    gripper_fault_fraction: float = 0.1
    max_scene_attempts: int = 25
    min_height: float = -0.005
    shared_layout_fraction: float = 0.0
    layout_shift: float = 1.0


@dataclass
class SceneLayout:
    """Initial object poses ``T_world_objects (2, 4, 4)`` and the gripper's start pose ``T_world_ee (4, 4)``."""

    T_world_objects: np.ndarray
    T_world_ee_start: np.ndarray


@dataclass
class DemoPlan:
    """One planned demonstration (``F`` frames): everything but its clouds.

    ``layout`` its initial scene; ``steps`` per frame the observed EE pose (world frame) and gripper state (gripper
    faults included: what a camera sees) and the action; ``state (F, 8)`` and ``action (F, 8)`` float32 in the
    data contract's layout (xyz, quaternion xyzw, gripper_open); ``T_world_objects (F, 2, 4, 4)`` the tracked
    object poses; ``held_object (F,)`` int8 (−1 when nothing is held); ``waypoint_frames`` the frame at which each
    waypoint is reached.
    """

    layout: SceneLayout
    steps: list[Step]
    state: np.ndarray
    action: np.ndarray
    T_world_objects: np.ndarray
    held_object: np.ndarray
    waypoint_frames: list[int]

    @property
    def num_frames(self) -> int:
        return len(self.steps)


@dataclass
class PseudoDemo:
    """One rendered demonstration (``F`` frames, ``P`` points), in the data contract's layout.

    ``points (F, P, 3)`` world frame; ``state (F, 8)`` and ``action (F, 8)`` are xyz, quaternion xyzw,
    gripper_open. Ground truth kept for tests and previews: ``point_labels (F, P)`` object index of each point,
    ``T_world_objects (F, 2, 4, 4)``, ``held_object (F,)`` (−1 when nothing is held), and
    ``waypoint_frames``, the frame at which each waypoint is reached.
    """

    task: PseudoTask
    layout: SceneLayout
    points: np.ndarray
    point_labels: np.ndarray
    state: np.ndarray
    action: np.ndarray
    T_world_objects: np.ndarray
    held_object: np.ndarray
    waypoint_frames: list[int] = field(default_factory=list)

    @property
    def num_frames(self) -> int:
        return len(self.state)


def sample_layout(objects: list[ObjectModel], rng: np.random.Generator, config: DemoConfig) -> SceneLayout:
    """Two non-overlapping objects on the table with a yaw within ±``object_max_yaw_deg``, and a top-down-ish start
    pose (tilted by up to ``start_max_tilt_deg``, turned about its approach axis by up to ``start_max_roll_deg``)."""
    max_yaw, max_roll = np.deg2rad(config.object_max_yaw_deg), np.deg2rad(config.start_max_roll_deg)
    for _ in range(100):
        positions = np.stack(
            [
                [rng.uniform(*config.object_x_range), rng.uniform(*config.object_y_range), 0.0]
                for _ in objects
            ]
        )
        if not _too_close(objects, positions, config.object_clearance):
            break
    else:
        positions[1, 1] = positions[0, 1] + np.sign(rng.normal()) * (
            objects[0].footprint_radius + objects[1].footprint_radius + config.object_clearance
        )
    T_world_objects = np.stack(
        [make_pose(position, Rotation.from_euler("z", rng.uniform(-max_yaw, max_yaw))) for position in positions]
    )
    tilt_axis = rng.normal(size=3)
    tilt_axis[2] = 0.0
    tilt_axis /= np.linalg.norm(tilt_axis)
    tilt = Rotation.from_rotvec(tilt_axis * np.deg2rad(rng.uniform(0.0, config.start_max_tilt_deg)))
    approach = tilt.apply([0.0, 0.0, -1.0])
    start = make_pose(
        [rng.uniform(*config.start_x_range), rng.uniform(*config.start_y_range), rng.uniform(*config.start_z_range)],
        look_rotation(approach, rng.uniform(-max_roll, max_roll)),
    )
    return SceneLayout(T_world_objects, start)


def shift_layout(T_world_objects_from: np.ndarray, T_world_objects_to: np.ndarray, fraction: float) -> np.ndarray:
    """Object poses ``(O, 4, 4)`` a ``fraction`` of the way from ``T_world_objects_from`` to ``T_world_objects_to``
    (both yawed about the vertical only, as :func:`sample_layout` places them): positions interpolated linearly,
    yaws along the shorter arc; ``fraction`` 0 returns ``T_world_objects_from`` unchanged."""
    shifted = T_world_objects_from.copy()
    if fraction == 0.0:
        return shifted
    for index, (T_from, T_to) in enumerate(zip(T_world_objects_from, T_world_objects_to, strict=True)):
        yaw_from = np.arctan2(T_from[1, 0], T_from[0, 0])
        turn = np.arctan2(T_to[1, 0], T_to[0, 0]) - yaw_from
        turn = (turn + np.pi) % (2.0 * np.pi) - np.pi
        position = (1.0 - fraction) * T_from[:3, 3] + fraction * T_to[:3, 3]
        shifted[index] = make_pose(position, Rotation.from_euler("z", yaw_from + fraction * turn))
    return shifted


def _too_close(objects: list[ObjectModel], positions: np.ndarray, clearance: float) -> bool:
    """Whether the two objects at ``positions (2, 3)`` (world frame) are closer on the table than their footprints
    and ``clearance`` allow."""
    gap = np.linalg.norm(positions[0, :2] - positions[1, :2])
    return bool(gap <= objects[0].footprint_radius + objects[1].footprint_radius + clearance)


def reference_path(task: PseudoTask, layout: SceneLayout) -> tuple[list[np.ndarray], list[bool], list[int]]:
    """The undisturbed path: uniformly spaced poses, gripper states, and the frame index of each waypoint.

    A gripper change at a waypoint adds one frame at the same pose with the new state.
    """
    poses = [layout.T_world_ee_start]
    grippers = [True]
    waypoint_frames = []
    for waypoint in task.waypoints:
        T_world_anchor = layout.T_world_objects[waypoint.anchor]
        target = T_world_anchor @ waypoint.T_anchor_ee
        dense = _segment(poses[-1], target, waypoint, T_world_anchor)
        resampled = resample_uniform(dense)
        resampled[-1] = target
        poses.extend(resampled[1:])
        grippers.extend([grippers[-1]] * (len(resampled) - 1))
        waypoint_frames.append(len(poses) - 1)
        if waypoint.gripper_open != grippers[-1]:
            poses.append(target)
            grippers.append(waypoint.gripper_open)
    return poses, grippers, waypoint_frames


def track_objects(
    steps: list[Step], objects: list[ObjectModel], layout: SceneLayout
) -> tuple[np.ndarray, np.ndarray]:
    """Object poses per frame ``(F, 2, 4, 4)`` and the held object per frame ``(F,)``.

    When the observed gripper goes from open to closed, the object whose surface is nearest the TCP is attached
    if it lies within ``GRASP_REACH``; it then moves rigidly with the EE until the gripper opens. Gripper-fault
    frames never attach or release: what is held stays held and keeps following the EE.
    """
    current = layout.T_world_objects.copy()
    poses = np.zeros((len(steps), len(objects), 4, 4))
    held = np.full(len(steps), -1, dtype=np.int8)
    holding, T_ee_object = -1, None
    previous_open = True
    for index, step in enumerate(steps):
        if step.gripper_fault:
            if holding >= 0:
                current[holding] = step.T_world_ee @ T_ee_object
            poses[index] = current
            held[index] = holding
            continue
        if previous_open and not step.gripper_open:
            holding = _nearest_within_reach(step.T_world_ee, objects, current)
            if holding >= 0:
                T_ee_object = invert(step.T_world_ee) @ current[holding]
        elif not previous_open and step.gripper_open:
            holding = -1
        if holding >= 0:
            current[holding] = step.T_world_ee @ T_ee_object
        previous_open = step.gripper_open
        poses[index] = current
        held[index] = holding
    return poses, held


def hold_signature(task: PseudoTask, layout: SceneLayout, objects: list[ObjectModel]) -> tuple[int, ...]:
    """Which object is held after each waypoint's gripper command on the undisturbed path (−1 for none)."""
    poses, grippers, waypoint_frames = reference_path(task, layout)
    _, held = track_objects(steps_from_states(poses, grippers), objects, layout)
    return tuple(int(held[min(frame + 1, len(held) - 1)]) for frame in waypoint_frames)


def plan_demo(
    task: PseudoTask,
    objects: list[ObjectModel],
    rng: np.random.Generator,
    config: DemoConfig,
    cameras: Sequence[CameraConfig] | None,
    expected_signature: tuple[int, ...] | None = None,
    T_world_objects_start: np.ndarray | None = None,
    layout_shift: float = 0.0,
) -> DemoPlan:
    """Plan one demonstration of ``task``, rendering nothing; scenes are resampled until one fits.

    A scene fits when neither the gripper nor an object goes below the table (``min_height``), every frame has a
    surface sample of some object inside some camera's image (``cameras``; None for clouds that need no camera,
    ``RenderConfig.cloud == "surface"``) and, if ``expected_signature`` is given, the same objects get grasped at
    the same waypoints as in the task's other demonstrations. ``T_world_objects_start (2, 4, 4)`` fixes the objects'
    initial poses (only the gripper's start pose is sampled), or with ``layout_shift`` > 0 the poses they move from
    by that fraction of the way to each sampled layout (:func:`shift_layout`; scenes whose objects then overlap are
    resampled). Every random draw comes from ``rng``.
    """
    reasons = []
    for _ in range(config.max_scene_attempts):
        layout = sample_layout(objects, rng, config)
        if T_world_objects_start is not None:
            T_world_objects_shifted = shift_layout(T_world_objects_start, layout.T_world_objects, layout_shift)
            if layout_shift > 0.0 and _too_close(objects, T_world_objects_shifted[:, :3, 3], config.object_clearance):
                reasons.append("the shifted objects overlap")
                continue
            layout = SceneLayout(T_world_objects_shifted, layout.T_world_ee_start)
        if expected_signature is not None and hold_signature(task, layout, objects) != expected_signature:
            reasons.append("grasps differ from the task's other demonstrations")
            continue
        poses, grippers, waypoint_frames = reference_path(task, layout)
        if rng.random() < config.disturbance_probability:
            steps = add_disturbance(poses, grippers, rng, keep_frames=waypoint_frames)
        else:
            steps = steps_from_states(poses, grippers)
        steps = add_gripper_faults(steps, config.gripper_fault_fraction, rng)
        T_world_objects, held = track_objects(steps, objects, layout)
        if min(step.T_world_ee[2, 3] for step in steps) < config.min_height:
            reasons.append("the gripper went below the table")
            continue
        if _lowest_point(objects, T_world_objects) < config.min_height:
            reasons.append("an object went below the table")
            continue
        if cameras is not None and not frames_in_view(objects, T_world_objects, cameras).all():
            reasons.append("a frame had no object in view")
            continue
        state = vectors_from_poses(
            np.stack([step.T_world_ee for step in steps]), np.array([step.gripper_open for step in steps])
        ).astype(np.float32)
        action = vectors_from_poses(
            np.stack([step.action_T_world_ee for step in steps]),
            np.array([step.action_gripper_open for step in steps]),
        ).astype(np.float32)
        frames = _frames_of(steps, [poses[frame] for frame in waypoint_frames])
        return DemoPlan(layout, steps, state, action, T_world_objects, held, frames)
    raise GenerationError(
        f"task {task.task_id}: no valid scene in {config.max_scene_attempts} attempts "
        f"({', '.join(sorted(set(reasons)))})"
    )


def render_demo(
    task: PseudoTask,
    objects: list[ObjectModel],
    plan: DemoPlan,
    renderer: PointCloudRenderer,
    rng: np.random.Generator,
    num_points: int,
) -> PseudoDemo:
    """Render every frame of ``plan`` with ``renderer`` and resample each cloud to ``num_points``
    (:func:`~..geometry.sampling.resample_indices`, whose draws come from ``rng``: a stream of its own, so that
    rendering never changes what is planned). A frame whose cloud comes out empty although :func:`plan_demo` found
    its objects in view (e.g. hidden behind the gripper from every camera) raises ``GenerationError``."""
    renderer.set_objects(objects)
    frames = plan.num_frames
    points = np.zeros((frames, num_points, 3), dtype=np.float32)
    labels = np.zeros((frames, num_points), dtype=np.int8)
    for index, step in enumerate(plan.steps):
        cloud, cloud_labels = renderer.render(list(plan.T_world_objects[index]), step.T_world_ee, step.gripper_open)
        if len(cloud) == 0:
            raise GenerationError(f"task {task.task_id}: frame {index} rendered no object point")
        chosen = resample_indices(cloud, num_points, rng)
        points[index] = cloud[chosen]
        labels[index] = cloud_labels[chosen]
    return _rendered(task, plan, points, labels)


def splat_inputs(
    objects: list[ObjectModel], scenes: Sequence[tuple[DemoPlan, int]], surface_samples: int
) -> dict[str, torch.Tensor]:
    """The :meth:`~..objects.splatting.SplatRenderer.visible` keyword arguments that splat ``B`` scenes of one task,
    each a planned demonstration of it and a frame index: ``object_points`` and ``object_normals`` ``(B, O, S, 3)``
    (the library's ``S = surface_samples`` per object, object frames), ``T_world_objects (B, O, 4, 4)``,
    ``T_world_ee (B, 4, 4)`` (the observed EE poses) float32 and ``gripper_open (B,)`` bool (the observed gripper)."""
    samples = [library_surface_samples(model.object_id, surface_samples) for model in objects]
    return {
        "object_points": torch.stack([points for points, _ in samples]).expand(len(scenes), -1, -1, -1),
        "object_normals": torch.stack([normals for _, normals in samples]).expand(len(scenes), -1, -1, -1),
        "T_world_objects": torch.as_tensor(
            np.stack([plan.T_world_objects[frame] for plan, frame in scenes]), dtype=torch.float32
        ),
        "T_world_ee": torch.as_tensor(np.stack([plan.steps[frame].T_world_ee for plan, frame in scenes]),
                                      dtype=torch.float32),
        "gripper_open": torch.as_tensor(np.array([plan.steps[frame].gripper_open for plan, frame in scenes])),
    }


def splat_demo(
    task: PseudoTask,
    objects: list[ObjectModel],
    plan: DemoPlan,
    renderer: SplatRenderer,
    rng: np.random.Generator,
    num_points: int,
    surface_samples: int,
    frames_per_call: int = 32,
) -> PseudoDemo:
    """:func:`render_demo` by z-buffer splatting: every frame of ``plan`` splatted by ``renderer`` from
    ``surface_samples`` per object (:func:`splat_inputs`), ``frames_per_call`` frames per call (a batch's result is
    the same as each frame's alone; memory grows with it, a few hundred bytes per sample and camera), and each
    cloud reduced to ``num_points`` on the host as the stream does on the CPU
    (:func:`~..objects.splatting.resample_visible`, whose draws come from ``rng``, frame after frame). Labels are
    the object index of each point. A frame no camera sees any object sample of raises ``GenerationError``."""
    points = np.zeros((plan.num_frames, num_points, 3), dtype=np.float32)
    labels = np.zeros((plan.num_frames, num_points), dtype=np.int8)
    for start in range(0, plan.num_frames, frames_per_call):
        frames = range(start, min(start + frames_per_call, plan.num_frames))
        posed, visible = renderer.visible(**splat_inputs(objects, [(plan, frame) for frame in frames], surface_samples))
        posed, visible = posed.cpu().numpy(), visible.cpu().numpy()
        empty = np.flatnonzero(~visible.any(axis=1))
        if len(empty):
            raise GenerationError(f"task {task.task_id}: frame {frames[empty[0]]} rendered no object point")
        chosen = resample_visible(visible, posed, num_points, rng)
        points[frames.start:frames.stop] = np.take_along_axis(posed, chosen[..., None], axis=1)
        labels[frames.start:frames.stop] = chosen // surface_samples
    return _rendered(task, plan, points, labels)


def frames_in_view(
    objects: list[ObjectModel], T_world_objects: np.ndarray, cameras: Sequence[CameraConfig]
) -> np.ndarray:
    """Which frames ``(F,)`` bool have a surface sample (``ObjectModel.surface_points``) of some object, posed by
    ``T_world_objects (F, O, 4, 4)``, inside some camera's image and depth range (the pinhole model of
    ``objects/rendering.py``; occlusion is not considered)."""
    clip_from_world = np.stack([camera_projection_matrix(camera) @ camera_view_matrix(camera) for camera in cameras])
    near = np.array([camera.near for camera in cameras])[None, :, None]
    far = np.array([camera.far for camera in cameras])[None, :, None]
    frames = len(T_world_objects)
    seen = np.zeros(frames, dtype=bool)
    for index, model in enumerate(objects):
        # the distinct poses only: an object at rest keeps one pose over many frames
        poses, inverse = np.unique(T_world_objects[:, index].reshape(frames, 16), axis=0, return_inverse=True)
        clip_from_object = clip_from_world[None] @ poses.reshape(-1, 1, 4, 4)  # (U, C, 4, 4)
        clip = model.surface_points @ np.swapaxes(clip_from_object[..., :3], -1, -2) + clip_from_object[..., None, :, 3]
        depth = clip[..., 3]  # (U, C, S)
        inside = (depth > near) & (depth < far) & (np.abs(clip[..., 0]) <= depth) & (np.abs(clip[..., 1]) <= depth)
        seen |= inside.any(axis=(1, 2))[inverse.reshape(-1)]
    return seen


def _rendered(task: PseudoTask, plan: DemoPlan, points: np.ndarray, labels: np.ndarray) -> PseudoDemo:
    """``plan`` with its clouds ``points (F, P, 3)`` and their object labels ``labels (F, P)``."""
    return PseudoDemo(
        task, plan.layout, points, labels, plan.state, plan.action, plan.T_world_objects, plan.held_object,
        list(plan.waypoint_frames),
    )


def _lowest_point(objects: list[ObjectModel], T_world_objects: np.ndarray) -> float:
    """Lowest world z of any object vertex over all frames, from poses ``(F, 2, 4, 4)``."""
    lowest = np.inf
    for index, model in enumerate(objects):
        z_rows = T_world_objects[:, index, 2, :3]
        heights = model.vertices @ z_rows.T + T_world_objects[:, index, 2, 3]
        lowest = min(lowest, float(heights.min()))
    return lowest


def _frames_of(steps: list[Step], waypoint_poses: list[np.ndarray]) -> list[int]:
    """Indices of the steps that reach ``waypoint_poses``, in order, after augmentation."""
    frames, index = [], 0
    for pose in waypoint_poses:
        while steps[index].T_world_ee is not pose:
            index += 1
        frames.append(index)
    return frames


def _nearest_within_reach(T_world_ee: np.ndarray, objects: list[ObjectModel], T_world_objects: np.ndarray) -> int:
    tcp = T_world_ee[:3, 3]
    distances = [
        np.linalg.norm(transform_points(pose, model.surface_points) - tcp, axis=1).min()
        for model, pose in zip(objects, T_world_objects, strict=True)
    ]
    nearest = int(np.argmin(distances))
    return nearest if distances[nearest] <= GRASP_REACH else -1


def _segment(T_start: np.ndarray, T_end: np.ndarray, waypoint: Waypoint, T_world_anchor: np.ndarray) -> np.ndarray:
    if waypoint.interpolation == "cubic":
        length = np.linalg.norm(T_end[:3, 3] - T_start[:3, 3])
        offsets = (waypoint.control_offsets * length) @ T_world_anchor[:3, :3].T
        return interpolate_cubic(T_start, T_end, offsets)
    if waypoint.interpolation == "spherical":
        return interpolate_spherical(T_start, T_end, transform_points(T_world_anchor, waypoint.center[None])[0])
    return interpolate_linear(T_start, T_end)
