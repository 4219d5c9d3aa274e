"""Partial segmented point clouds by z-buffer splatting of pre-sampled surface points, batched in torch.

The accelerator counterpart of :class:`~.rendering.PointCloudRenderer` with ``cloud="cameras"`` (the reference it
is tested against): the same cameras (:func:`~.rendering.default_cameras`), the same pinhole model
(:func:`~.rendering.camera_view_matrix`, :func:`~.rendering.camera_projection_matrix`), the gripper occluding but
never part of the cloud, the table not drawn. Instead of rasterising triangles it splats dense surface samples.

The maths, for a batch of ``B`` scenes, each with ``O`` objects of ``S`` surface points ``p`` (object frame):

1. **Pose.** ``x = T_world_object · p``; the gripper's samples ``g`` (EE frame, open or closed) become
   ``T_world_ee · g``. All ``N = O·S (+ G)`` points of a scene are splatted together.
2. **Project.** For camera ``c`` with view ``V_c`` and projection ``K_c`` (OpenGL, as pybullet's):
   ``(X, Y, Z, W) = K_c V_c (x, 1)``; ``W = −z_eye`` is the depth along the optical axis; the normalised device
   coordinates ``u = X/W``, ``v = Y/W`` fall on pixel ``col = ⌊(u + 1)/2 · w⌋``, ``row = ⌊(1 − v)/2 · h⌋``
   of a ``w × h`` z-buffer. Points with ``W ≤ near``, ``W ≥ far`` or outside ``[−1, 1]²`` are not seen by ``c``.
3. **Z-buffer.** ``zbuf[b, c, pixel] = min W`` over the points of scene ``b`` that land on the pixel or within
   ``splat_radius`` pixels of it (a point covers a ``(2r+1)²`` square, which closes the gaps between samples so
   that a back surface does not show through a front one): one ``scatter_reduce(..., reduce="amin")`` over the
   flattened ``(b, c, pixel)`` indices.
4. **Visibility.** A point is seen by camera ``c`` when ``W ≤ zbuf[b, c, its pixel] + depth_tolerance`` and, when
   outward normals ``n`` are given, ``n · (eye_c − x) > 0`` (back-face culling: without it a band of hidden
   faces about ``depth_tolerance`` wide survives at silhouette edges). It is in the cloud when some camera sees
   it (the union of the cameras) and it is an object point (the gripper's points only fill the z-buffer). A
   surface that no camera sees — the underside of an object on the table, a face turned away from all cameras,
   a part hidden behind the other object or the gripper — keeps no point.
5. **Resample.** The visible points of each scene are reduced to ``P`` by farthest-point sampling
   (:func:`~..geometry.masked_fps.masked_farthest_point_sampling`), or repeated in FPS order when fewer. The start
   is the visible point with the smallest key in a permutation of ``0 … N−1`` drawn from ``seed``, so a result
   depends only on the scene and the seed, never on the other scenes of the batch. On the host,
   :func:`resample_visible` reduces the output of :meth:`SplatRenderer.visible` as the dataset path reduces
   pybullet's clouds instead (bucket FPS, :func:`~..geometry.sampling.resample_indices`).

Sizes: a z-buffer pixel and the sample spacing must match — a pixel much smaller than the spacing lets back faces
leak through, a much larger one erodes silhouettes. The defaults (``DEFAULT_SURFACE_SAMPLES`` points per object,
a 480 × 360 z-buffer, radius 1, 6 mm tolerance, normals given) reach 1.2–2.5 mm (splat → pybullet) and
1.6–3.0 mm (pybullet → splat) mean Chamfer distance to the pybullet clouds of the visible samples before
resampling (``tests/objects/test_splatting.py`` states the figures per scene). Every object of a batch carries
the same number ``S`` of samples; memory grows as ``B · C · N`` (a few hundred bytes per point and camera).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh

from ..geometry.masked_fps import masked_farthest_point_sampling
from ..geometry.sampling import resample_indices
from .library import ObjectModel, load_object
from .rendering import CameraConfig, camera_projection_matrix, camera_view_matrix, default_cameras

DEFAULT_SURFACE_SAMPLES = 8192
GRIPPER_SURFACE_SAMPLES = 4096
_GRIPPER_FINGER_GAP = {True: 0.08, False: 0.0}


@dataclass
class SplatConfig:
    """How :class:`SplatRenderer` observes a scene.

    ``cameras`` as in :class:`~.rendering.RenderConfig`; ``zbuffer_resolution`` ``(w, h)`` pixels of each camera's
    z-buffer over its full field of view; ``splat_radius`` pixels each point covers around its own (see the module
    docstring); ``depth_tolerance`` (m) by which a point may lie behind its pixel's z-buffer value and still count
    as seen; ``gripper_occludes`` as in ``RenderConfig``.
    """

    cameras: list[CameraConfig] = field(default_factory=default_cameras)
    zbuffer_resolution: tuple[int, int] = (480, 360)
    splat_radius: int = 1
    depth_tolerance: float = 0.006
    gripper_occludes: bool = True

    def __post_init__(self):
        if not self.cameras:
            raise ValueError("SplatConfig needs at least one camera")
        if len(self.zbuffer_resolution) != 2 or min(self.zbuffer_resolution) < 1:
            raise ValueError(f"zbuffer_resolution must be (w, h) ≥ 1, got {self.zbuffer_resolution}")
        if self.splat_radius < 0 or self.depth_tolerance < 0:
            raise ValueError("splat_radius and depth_tolerance must be ≥ 0")


@dataclass
class SplatCloud:
    """A batch of fixed-size partial clouds.

    ``points_world (B, P, 3)`` in the world frame; ``labels (B, P)`` int64 object index of each point;
    ``source (B, P)`` int64 index of each point in the flattened ``(O·S)`` input samples (object ``source // S``);
    ``num_visible (B,)`` int64 visible samples before resampling. A scene with ``num_visible == 0`` (no object in
    any camera's view) has zeros in ``points_world`` and −1 in ``labels`` and ``source``.
    """

    points_world: torch.Tensor
    labels: torch.Tensor
    source: torch.Tensor
    num_visible: torch.Tensor


def object_surface_samples(
    model: ObjectModel, num_points: int = DEFAULT_SURFACE_SAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform samples of ``model``'s mesh, denser than ``model.surface_points`` (1,024), for splatting.

    Returns:
        ``points (num_points, 3)`` and outward ``normals (num_points, 3)`` float32 in the object's frame.
    """
    mesh = trimesh.Trimesh(vertices=model.vertices, faces=model.faces, process=False)
    points, face_index = trimesh.sample.sample_surface(mesh, num_points, seed=seed)
    return np.asarray(points, dtype=np.float32), np.asarray(mesh.face_normals[face_index], dtype=np.float32)


@functools.lru_cache(maxsize=256)
def library_surface_samples(
    object_id: str, num_points: int = DEFAULT_SURFACE_SAMPLES, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`object_surface_samples` of the library object ``object_id`` as CPU float32 tensors ``points
    (num_points, 3)`` and ``normals (num_points, 3)``, object frame; cached per process (the 256 objects used last,
    about 200 KB each at the default size). Treat them as read-only."""
    points, normals = object_surface_samples(load_object(object_id), num_points, seed)
    return torch.from_numpy(points), torch.from_numpy(normals)


def gripper_surface_samples(gripper_open: bool, num_points: int = GRIPPER_SURFACE_SAMPLES, seed: int = 0) -> np.ndarray:
    """Area-uniform samples ``(num_points, 3)`` float32 of the occluding gripper's surface, EE (TCP) frame.

    The same solids as ``PointCloudRenderer._make_gripper``: a 5 × 20 × 6 cm palm centred 8 cm back along the
    approach axis z, two 2 × 2 × 5 cm fingers at ``y = ±(gap/2 + 1 cm)``, ``z = −2.5 cm`` (gap 8 cm open, 0
    closed) and a wrist cylinder of radius 4 cm and length 10 cm centred at ``z = −16 cm``.
    """
    finger_y = _GRIPPER_FINGER_GAP[bool(gripper_open)] / 2 + 0.01
    parts = [
        trimesh.creation.box(extents=[0.05, 0.2, 0.06], transform=_translation(0, 0, -0.08)),
        trimesh.creation.box(extents=[0.02, 0.02, 0.05], transform=_translation(0, finger_y, -0.025)),
        trimesh.creation.box(extents=[0.02, 0.02, 0.05], transform=_translation(0, -finger_y, -0.025)),
        trimesh.creation.cylinder(radius=0.04, height=0.1, sections=32, transform=_translation(0, 0, -0.16)),
    ]
    mesh = trimesh.util.concatenate(parts)
    points, _ = trimesh.sample.sample_surface(mesh, num_points, seed=seed)
    return np.asarray(points, dtype=np.float32)


class SplatRenderer:
    """Renders batches of partial segmented clouds on ``device`` (CPU or CUDA, the same code).

    Args:
        config: cameras and splatting sizes (:class:`SplatConfig`).
        device: where the cameras and the gripper's samples live; inputs are moved there.
    """

    def __init__(self, config: SplatConfig | None = None, device: torch.device | str = "cpu"):
        self.config = config or SplatConfig()
        self.device = torch.device(device)
        clip_from_world = [camera_projection_matrix(c) @ camera_view_matrix(c) for c in self.config.cameras]
        # (C, 4, 4) world → clip, float64 on the host for exactness, float32 on the device
        self.clip_from_world = torch.as_tensor(np.stack(clip_from_world), dtype=torch.float32, device=self.device)
        self.near = torch.tensor([c.near for c in self.config.cameras], dtype=torch.float32, device=self.device)
        self.eyes = torch.tensor([c.eye for c in self.config.cameras], dtype=torch.float32, device=self.device)
        self.far = torch.tensor([c.far for c in self.config.cameras], dtype=torch.float32, device=self.device)
        # (2, G, 3): index 0 closed, 1 open, EE frame
        self.gripper_points = torch.as_tensor(
            np.stack([gripper_surface_samples(False), gripper_surface_samples(True)]), device=self.device
        )

    def visible(
        self,
        object_points: torch.Tensor,
        T_world_objects: torch.Tensor,
        T_world_ee: torch.Tensor | None = None,
        gripper_open: torch.Tensor | None = None,
        object_normals: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Which posed surface samples some camera sees.

        Args:
            object_points: ``(B, O, S, 3)`` or ``(O, S, 3)`` (shared by the batch) surface samples, object frames.
            T_world_objects: ``(B, O, 4, 4)`` object poses.
            T_world_ee: ``(B, 4, 4)`` gripper (TCP) poses, or ``None`` for no gripper.
            gripper_open: ``(B,)`` bool, which finger opening occludes; ``None`` means open.
            object_normals: outward normals of ``object_points``, same shape, object frames, or ``None``. With
                normals a camera does not see a sample whose normal faces away from it (back-face culling), which
                removes the thin band of hidden faces that the depth tolerance would otherwise let through at
                silhouette edges (e.g. the underside of an object within a few mm of its footprint's rim).

        Returns:
            ``points_world (B, O·S, 3)`` float32 posed samples and ``visible (B, O·S)`` bool.
        """
        object_points, T_world_objects, T_world_ee, gripper_open = self._check(
            object_points, T_world_objects, T_world_ee, gripper_open
        )
        facing = None
        if object_normals is not None:
            object_normals = _as_tensor(object_normals, "object_normals", self.device)
            if object_normals.ndim == 3:
                object_normals = object_normals.expand(object_points.shape[0], *object_normals.shape)
            if object_normals.shape != object_points.shape or not torch.isfinite(object_normals).all():
                raise ValueError(
                    f"object_normals must be finite with the shape of object_points {tuple(object_points.shape)}, "
                    f"got {tuple(object_normals.shape)}"
                )
        batch, num_objects, num_samples, _ = object_points.shape
        points_world = _transform(T_world_objects, object_points).reshape(batch, -1, 3)
        if object_normals is not None:
            rotation_only = T_world_objects.clone()
            rotation_only[..., :3, 3] = 0.0
            normals_world = _transform(rotation_only, object_normals).reshape(batch, -1, 3)
            to_eye = self.eyes[None, :, None] - points_world[:, None]  # (B, C, N, 3)
            facing = (to_eye * normals_world[:, None]).sum(-1) > 0  # (B, C, N)
        occluders = points_world
        if T_world_ee is not None and self.config.gripper_occludes:
            gripper = self.gripper_points[gripper_open.long()]  # (B, G, 3)
            gripper_world = _transform(T_world_ee, gripper)
            occluders = torch.cat([points_world, gripper_world], dim=1)
        return points_world, self._seen(occluders, points_world.shape[1], facing)

    def render(
        self,
        object_points: torch.Tensor,
        T_world_objects: torch.Tensor,
        T_world_ee: torch.Tensor | None = None,
        gripper_open: torch.Tensor | None = None,
        num_points: int = 2048,
        seed: int = 0,
        object_normals: torch.Tensor | None = None,
    ) -> SplatCloud:
        """The partial segmented clouds of a batch of scenes, ``num_points`` each (see :meth:`visible` for the
        inputs and the module docstring for the maths). Deterministic for a ``seed``; each scene's result is the
        same alone or in any batch.

        Returns:
            :class:`SplatCloud` with ``points_world (B, P, 3)``, ``labels (B, P)``, ``source (B, P)``,
            ``num_visible (B,)``, ``P = num_points``.
        """
        if num_points < 1:
            raise ValueError(f"num_points must be ≥ 1, got {num_points}")
        points_world, visible = self.visible(object_points, T_world_objects, T_world_ee, gripper_open, object_normals)
        batch, total, _ = points_world.shape
        num_samples = total // (T_world_objects.shape[-3])
        num_visible = visible.sum(dim=1)
        # compact: visible points first, in source order (stable), cut to the most any scene has
        order = torch.argsort((~visible).to(torch.int8), dim=1, stable=True)
        width = max(int(num_visible.max()), 1)
        order = order[:, :width]
        candidates = torch.gather(points_world, 1, order[..., None].expand(-1, -1, 3))
        valid = torch.gather(visible, 1, order)
        # seeded start: the visible sample with the smallest key
        keys = torch.randperm(total, generator=torch.Generator().manual_seed(seed)).to(points_world.device)
        start = torch.where(valid, keys[order], total).argmin(dim=1)
        chosen = masked_farthest_point_sampling(candidates, valid, num_points, start)
        source = torch.gather(order, 1, chosen)
        empty = (num_visible == 0)[:, None]
        points = torch.gather(points_world, 1, source[..., None].expand(-1, -1, 3))
        points = torch.where(empty[..., None], 0.0, points)
        source = torch.where(empty, -1, source)
        labels = torch.where(empty, -1, source // num_samples)
        return SplatCloud(points_world=points, labels=labels, source=source, num_visible=num_visible)

    def _seen(self, points_world: torch.Tensor, num_outputs: int, facing: torch.Tensor | None) -> torch.Tensor:
        """``(B, N, 3)`` splatted points → ``(B, num_outputs)`` bool: is each of the first ``num_outputs`` seen
        (by a camera that it faces, when ``facing (B, C, num_outputs)`` is given)."""
        batch, num_points, _ = points_world.shape
        width, height = self.config.zbuffer_resolution
        num_cameras = self.clip_from_world.shape[0]
        M = self.clip_from_world[None, :, None]  # (1, C, 1, 4, 4)
        x = points_world[:, None, :, None, :]  # (B, 1, N, 1, 3)
        # (B, C, N, 4), elementwise (the same alone or in a batch) with no (…, 4, 3) intermediate
        clip = M[..., 0] * x[..., 0] + M[..., 1] * x[..., 1] + M[..., 2] * x[..., 2] + M[..., 3]
        depth = clip[..., 3]
        in_depth = (depth > self.near[None, :, None]) & (depth < self.far[None, :, None])
        safe_depth = torch.where(in_depth, depth, 1.0)
        u, v = clip[..., 0] / safe_depth, clip[..., 1] / safe_depth
        in_view = in_depth & (u.abs() <= 1.0) & (v.abs() <= 1.0)
        col = ((u + 1.0) * 0.5 * width).floor().long().clamp(0, width - 1)
        row = ((1.0 - v) * 0.5 * height).floor().long().clamp(0, height - 1)
        image = (torch.arange(batch, device=self.device)[:, None, None] * num_cameras
                 + torch.arange(num_cameras, device=self.device)[None, :, None])  # (B, C, 1)
        num_pixels = batch * num_cameras * height * width
        zbuffer = torch.full((num_pixels + 1,), torch.inf, dtype=depth.dtype, device=self.device)
        radius = self.config.splat_radius
        splat_depth = torch.where(in_view, depth, torch.inf)
        for d_row in range(-radius, radius + 1):
            for d_col in range(-radius, radius + 1):
                r, c = row + d_row, col + d_col
                inside = in_view & (r >= 0) & (r < height) & (c >= 0) & (c < width)
                pixel = (image * height + r.clamp(0, height - 1)) * width + c.clamp(0, width - 1)
                pixel = torch.where(inside, pixel, num_pixels)  # the last slot collects what falls off the image
                zbuffer.scatter_reduce_(0, pixel.reshape(-1), splat_depth.reshape(-1), reduce="amin")
        centre = (image * height + row) * width + col
        seen = in_view & (depth <= zbuffer[centre] + self.config.depth_tolerance)  # (B, C, N)
        seen = seen[..., :num_outputs]
        if facing is not None:
            seen = seen & facing
        return seen.any(dim=1)

    def _check(self, object_points, T_world_objects, T_world_ee, gripper_open):
        """Validate shapes and finiteness, move to the device as float32, broadcast shared samples."""
        object_points = _as_tensor(object_points, "object_points", self.device)
        T_world_objects = _as_tensor(T_world_objects, "T_world_objects", self.device)
        if T_world_objects.ndim != 4 or T_world_objects.shape[-2:] != (4, 4) or T_world_objects.shape[:2].numel() == 0:
            raise ValueError(
                f"T_world_objects must have shape (B, O, 4, 4) with B, O ≥ 1, got {tuple(T_world_objects.shape)}"
            )
        batch, num_objects = T_world_objects.shape[:2]
        if object_points.ndim == 3:
            object_points = object_points.expand(batch, *object_points.shape)
        if object_points.ndim != 4 or object_points.shape[-1] != 3 or object_points.shape[:2] != (batch, num_objects):
            raise ValueError(
                f"object_points must have shape (B, O, S, 3) or (O, S, 3) with B={batch}, O={num_objects} "
                f"from T_world_objects, got {tuple(object_points.shape)}"
            )
        if object_points.shape[2] == 0:
            raise ValueError("object_points needs at least one sample per object (S ≥ 1)")
        _check_pose(T_world_objects, "T_world_objects")
        if T_world_ee is not None:
            T_world_ee = _as_tensor(T_world_ee, "T_world_ee", self.device)
            if T_world_ee.shape != (batch, 4, 4):
                raise ValueError(
                    f"T_world_ee must have shape (B, 4, 4) = ({batch}, 4, 4), got {tuple(T_world_ee.shape)}"
                )
            _check_pose(T_world_ee, "T_world_ee")
            if gripper_open is None:
                gripper_open = torch.ones(batch, dtype=torch.bool, device=self.device)
            gripper_open = torch.as_tensor(gripper_open, device=self.device)
            if gripper_open.shape != (batch,):
                raise ValueError(f"gripper_open must have shape (B,) = ({batch},), got {tuple(gripper_open.shape)}")
            gripper_open = gripper_open.bool()
        if not torch.isfinite(object_points).all():
            raise ValueError("object_points contains non-finite values")
        return object_points, T_world_objects, T_world_ee, gripper_open


def resample_visible(
    visible: np.ndarray, points_world: np.ndarray, num_points: int, rng: np.random.Generator
) -> np.ndarray:
    """Each scene's visible samples reduced to ``num_points`` on the host, as the dataset path reduces pybullet's
    clouds (:func:`~..geometry.sampling.resample_indices`, bucket FPS; its draws from ``rng``, scene after scene).

    Args:
        visible: ``(B, N)`` bool, :meth:`SplatRenderer.visible`'s second output; every scene must see a sample.
        points_world: ``(B, N, 3)`` the posed samples (world frame), its first output.

    Returns:
        ``(B, num_points)`` int64 indices into ``N`` (object ``index // S`` for ``S`` samples per object).
    """
    if not visible.any(axis=1).all():
        raise ValueError("every scene needs a visible sample to resample")
    chosen = np.empty((len(visible), num_points), dtype=np.int64)
    for scene, (seen, posed) in enumerate(zip(visible, points_world, strict=True)):
        indices = np.flatnonzero(seen)
        chosen[scene] = indices[resample_indices(posed[indices], num_points, rng)]
    return chosen


def _as_tensor(value, name: str, device: torch.device) -> torch.Tensor:
    tensor = torch.as_tensor(value, device=device)
    if not (tensor.is_floating_point()):
        raise ValueError(f"{name} must be a floating-point tensor, got {tensor.dtype}")
    return tensor.to(torch.float32)


def _check_pose(T: torch.Tensor, name: str) -> None:
    if not torch.isfinite(T).all():
        raise ValueError(f"{name} contains non-finite values")
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], device=T.device)
    if not torch.allclose(T[..., 3, :], bottom.expand_as(T[..., 3, :]), atol=1e-5):
        raise ValueError(f"{name} must be homogeneous rigid transforms with last row (0, 0, 0, 1)")


def _transform(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``T (..., 4, 4)`` applied to ``points (..., N, 3)`` (broadcast), elementwise rather than by a batched matrix
    product, so that a scene's result does not depend on the batch it is in."""
    R, t = T[..., None, :3, :3], T[..., None, :3, 3]
    return R[..., 0] * points[..., 0:1] + R[..., 1] * points[..., 1:2] + R[..., 2] * points[..., 2:3] + t


def _translation(x: float, y: float, z: float) -> np.ndarray:
    transform = np.eye(4)
    transform[:3, 3] = (x, y, z)
    return transform


__all__ = [
    "DEFAULT_SURFACE_SAMPLES",
    "SplatCloud",
    "SplatConfig",
    "SplatRenderer",
    "gripper_surface_samples",
    "library_surface_samples",
    "object_surface_samples",
    "resample_visible",
]

