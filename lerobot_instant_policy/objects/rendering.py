"""Segmented point clouds from simulated depth cameras (pybullet's TinyRenderer, no window, no physics).

Three cameras look at the tabletop. Each renders depth and a segmentation mask; pixels of the task objects
are back-projected to the world frame, the gripper occludes but is masked out, and the table is not drawn
(it occludes nothing above it and is never part of the cloud). Each camera renders only the part of its
image that the objects can cover (a crop of a ``full_resolution`` sensor, at most ``max_crop_pixels`` wide);
this keeps rendering cheap without changing what the camera sees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pybullet

from ..geometry.se3 import pose_to_pos_quat
from .library import ObjectModel

_HIDDEN_POSITION = (0.0, 0.0, -50.0)
CLOUD_SOURCES = ("cameras", "surface")
RENDERERS = ("pybullet", "splat")


@dataclass
class CameraConfig:
    """A pinhole depth camera looking from ``eye`` at ``target`` (world frame, m)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.5, 0.0, 0.05)
    fov_deg: float = 55.0
    full_resolution: tuple[int, int] = (640, 480)
    near: float = 0.05
    far: float = 3.0


def default_cameras() -> list[CameraConfig]:
    """Front camera and two shoulder cameras around a workspace centred at (0.5, 0, 0)."""
    return [
        CameraConfig(eye=(1.25, 0.0, 0.55)),
        CameraConfig(eye=(0.15, 0.55, 0.70)),
        CameraConfig(eye=(0.15, -0.55, 0.70)),
    ]


@dataclass
class RenderConfig:
    """How a frame's cloud is observed.

    ``cloud``: ``"cameras"`` renders the segmented depth of ``cameras`` (partial views, occlusion by the gripper and
    by the other object: what a robot sees); ``"surface"`` takes every object's complete surface sample
    (``ObjectModel.surface_points``) in its current pose, with no camera — an idealised observation for ablations
    and curricula. ``renderer``, for ``"cameras"``: ``"pybullet"`` rasterises the meshes (:class:`PointCloudRenderer`,
    cropped to ``max_crop_pixels``); ``"splat"`` splats dense surface samples into z-buffers
    (:class:`~.splatting.SplatRenderer` at its default sizes, as the pseudo-task stream renders).
    """

    cameras: list[CameraConfig] = field(default_factory=default_cameras)
    max_crop_pixels: int = 80
    gripper_occludes: bool = True
    cloud: str = "cameras"
    renderer: str = "pybullet"

    def __post_init__(self):
        if self.cloud not in CLOUD_SOURCES:
            raise ValueError(f"cloud must be one of {list(CLOUD_SOURCES)}, got {self.cloud!r}")
        if self.renderer not in RENDERERS:
            raise ValueError(f"render.renderer must be one of {list(RENDERERS)}, got {self.renderer!r}")
        if self.renderer == "splat" and self.cloud != "cameras":
            raise ValueError(f"render.renderer 'splat' renders the cameras' views; it needs render.cloud 'cameras', "
                             f"got {self.cloud!r}")


class PointCloudRenderer:
    """Owns one pybullet DIRECT client; renders world-frame object points for given object and EE poses."""

    def __init__(self, config: RenderConfig | None = None):
        self.config = config or RenderConfig()
        self.client = pybullet.connect(pybullet.DIRECT)
        self._shapes: dict[str, int] = {}
        self._object_bodies: list[int] = []
        self._object_corners: list[np.ndarray] = []
        self._surface_points: list[np.ndarray] = []
        self._label_of_body = np.full(1, -1, dtype=np.int8)
        self._views = [camera_view_matrix(camera) for camera in self.config.cameras]
        self._projections = [camera_projection_matrix(camera) for camera in self.config.cameras]
        self._gripper_bodies = {
            True: self._make_gripper(finger_gap=0.08),
            False: self._make_gripper(finger_gap=0.0),
        }

    def close(self) -> None:
        if pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)

    def __enter__(self) -> PointCloudRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_objects(self, objects: list[ObjectModel]) -> None:
        """Replace the scene's objects (visual shapes are cached per object id)."""
        for body in self._object_bodies:
            pybullet.removeBody(body, physicsClientId=self.client)
        self._object_bodies = []
        self._object_corners = []
        self._surface_points = [model.surface_points for model in objects]
        for model in objects:
            if model.object_id not in self._shapes:
                self._shapes[model.object_id] = pybullet.createVisualShape(
                    pybullet.GEOM_MESH,
                    vertices=model.vertices.tolist(),
                    indices=model.faces.reshape(-1).tolist(),
                    rgbaColor=[0.7, 0.6, 0.5, 1.0],
                    physicsClientId=self.client,
                )
            body = pybullet.createMultiBody(
                baseMass=0,
                baseVisualShapeIndex=self._shapes[model.object_id],
                basePosition=_HIDDEN_POSITION,
                physicsClientId=self.client,
            )
            self._object_bodies.append(body)
            lower, upper = model.vertices.min(axis=0), model.vertices.max(axis=0)
            self._object_corners.append(
                np.array([[x, y, z] for x in (lower[0], upper[0]) for y in (lower[1], upper[1]) for z in (lower[2], upper[2])])
            )
        # body id → object index; the last entry (−1) also serves the mask's background −1 and every other body
        self._label_of_body = np.full(max(self._object_bodies, default=0) + 2, -1, dtype=np.int8)
        self._label_of_body[self._object_bodies] = np.arange(len(self._object_bodies))

    def render(
        self, T_world_objects: list[np.ndarray], T_world_ee: np.ndarray, gripper_open: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Render the segmented cloud.

        Args:
            T_world_objects: one ``(4, 4)`` pose per object set with ``set_objects``.
            T_world_ee: ``(4, 4)`` gripper (TCP) pose; the gripper only occludes.
            gripper_open: which finger opening to draw.

        Returns:
            ``points (P, 3)`` float32 in the world frame and ``labels (P,)`` int8, the object index of each point.
            ``P`` may be 0 when no object is in any camera's view.
        """
        if len(T_world_objects) != len(self._object_bodies):
            raise ValueError(f"expected {len(self._object_bodies)} object poses, got {len(T_world_objects)}")
        if self.config.cloud == "surface":
            return self._surface_cloud(T_world_objects)
        for body, pose in zip(self._object_bodies, T_world_objects, strict=True):
            position, quat = pose_to_pos_quat(pose)
            pybullet.resetBasePositionAndOrientation(body, position, quat, physicsClientId=self.client)
        self._place_gripper(T_world_ee, gripper_open)
        corners = np.concatenate(
            [corners @ pose[:3, :3].T + pose[:3, 3] for corners, pose in zip(self._object_corners, T_world_objects, strict=True)]
        )
        points, labels = [], []
        for camera, view, projection in zip(self.config.cameras, self._views, self._projections, strict=True):
            camera_points, camera_labels = self._render_camera(camera, view, projection, corners)
            points.append(camera_points)
            labels.append(camera_labels)
        return np.concatenate(points).astype(np.float32), np.concatenate(labels).astype(np.int8)

    def _surface_cloud(self, T_world_objects: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Every object's surface sample ``(S, 3)`` posed by ``T_world_objects``: ``points (ΣS, 3)``, ``labels``."""
        poses = zip(self._surface_points, T_world_objects, strict=True)
        points = [surface @ pose[:3, :3].T + pose[:3, 3] for surface, pose in poses]
        labels = [np.full(len(surface), index, dtype=np.int8) for index, surface in enumerate(self._surface_points)]
        return np.concatenate(points).astype(np.float32), np.concatenate(labels)

    def _render_camera(
        self, camera: CameraConfig, view: np.ndarray, projection: np.ndarray, corners_world: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        return render_segmented_points(
            self.client, camera, view, projection, corners_world, self._label_of_body, self.config.max_crop_pixels
        )

    def _place_gripper(self, T_world_ee: np.ndarray, gripper_open: bool) -> None:
        position, quat = pose_to_pos_quat(T_world_ee)
        for state, body in self._gripper_bodies.items():
            visible = self.config.gripper_occludes and state == gripper_open
            pybullet.resetBasePositionAndOrientation(
                body, position if visible else _HIDDEN_POSITION, quat, physicsClientId=self.client
            )

    def _make_gripper(self, finger_gap: float) -> int:
        """A Panda-hand-like gripper in the EE (TCP) frame: z is the approach axis, y the finger axis."""
        finger_y = finger_gap / 2 + 0.01
        shape = pybullet.createVisualShapeArray(
            shapeTypes=[pybullet.GEOM_BOX, pybullet.GEOM_BOX, pybullet.GEOM_BOX, pybullet.GEOM_CYLINDER],
            halfExtents=[[0.025, 0.1, 0.03], [0.01, 0.01, 0.025], [0.01, 0.01, 0.025], [0, 0, 0]],
            radii=[0, 0, 0, 0.04],
            lengths=[0, 0, 0, 0.1],
            visualFramePositions=[[0, 0, -0.08], [0, finger_y, -0.025], [0, -finger_y, -0.025], [0, 0, -0.16]],
            physicsClientId=self.client,
        )
        return pybullet.createMultiBody(
            baseMass=0, baseVisualShapeIndex=shape, basePosition=_HIDDEN_POSITION, physicsClientId=self.client
        )


def render_segmented_points(
    client: int,
    camera: CameraConfig,
    view: np.ndarray,
    projection: np.ndarray,
    corners_world: np.ndarray,
    label_of_body: np.ndarray,
    max_crop_pixels: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project one camera's labelled pixels in pybullet client ``client`` to world points.

    Only the crop of the image that ``corners_world (C, 3)`` (corners of the objects' bounding boxes) can cover
    is rendered, at most ``max_crop_pixels`` wide and high. ``label_of_body`` maps a segmentation body id to a
    label (its last entry, −1, serves the background and every unlabelled body). ``view`` and ``projection``
    are ``(4, 4)`` (``camera_view_matrix`` / ``camera_projection_matrix``).

    Returns:
        ``points (P, 3)`` in the world frame and ``labels (P,)`` of the labelled pixels (``P`` may be 0).
    """
    clip = np.c_[corners_world, np.ones(len(corners_world))] @ (projection @ view).T
    if np.any(clip[:, 3] <= camera.near):
        x_range, y_range = (-1.0, 1.0), (-1.0, 1.0)
    else:
        ndc = clip[:, :2] / clip[:, 3:4]
        x_range = (max(ndc[:, 0].min(), -1.0), min(ndc[:, 0].max(), 1.0))
        y_range = (max(ndc[:, 1].min(), -1.0), min(ndc[:, 1].max(), 1.0))
    if x_range[0] >= x_range[1] or y_range[0] >= y_range[1]:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int8)
    full_width, full_height = camera.full_resolution
    width = int(np.clip(np.ceil((x_range[1] - x_range[0]) / 2 * full_width), 2, max_crop_pixels))
    height = int(np.clip(np.ceil((y_range[1] - y_range[0]) / 2 * full_height), 2, max_crop_pixels))
    crop = np.eye(4)
    crop[0, 0] = 2.0 / (x_range[1] - x_range[0])
    crop[0, 3] = -(x_range[0] + x_range[1]) / (x_range[1] - x_range[0])
    crop[1, 1] = 2.0 / (y_range[1] - y_range[0])
    crop[1, 3] = -(y_range[0] + y_range[1]) / (y_range[1] - y_range[0])
    cropped_projection = crop @ projection
    _, _, _, depth, segmentation = pybullet.getCameraImage(
        width,
        height,
        viewMatrix=view.T.reshape(-1).tolist(),
        projectionMatrix=cropped_projection.T.reshape(-1).tolist(),
        renderer=pybullet.ER_TINY_RENDERER,
        physicsClientId=client,
    )
    depth = np.asarray(depth, dtype=np.float64).reshape(height, width)
    segmentation = np.asarray(segmentation).reshape(height, width)
    labels_image = label_of_body[np.clip(segmentation, -1, len(label_of_body) - 1)]
    rows, cols = np.nonzero(labels_image >= 0)
    if len(rows) == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int8)
    ndc = np.stack(
        [
            2.0 * (cols + 0.5) / width - 1.0,
            1.0 - 2.0 * (rows + 0.5) / height,
            2.0 * depth[rows, cols] - 1.0,
            np.ones(len(rows)),
        ],
        axis=1,
    )
    world = ndc @ np.linalg.inv(cropped_projection @ view).T
    return world[:, :3] / world[:, 3:4], labels_image[rows, cols]


def camera_view_matrix(camera: CameraConfig) -> np.ndarray:
    """The ``(4, 4)`` world → camera (OpenGL) view matrix of ``camera``."""
    view = pybullet.computeViewMatrix(camera.eye, camera.target, (0.0, 0.0, 1.0))
    return np.asarray(view, dtype=np.float64).reshape(4, 4).T


def camera_projection_matrix(camera: CameraConfig) -> np.ndarray:
    """The ``(4, 4)`` OpenGL projection matrix of ``camera``'s full sensor."""
    width, height = camera.full_resolution
    projection = pybullet.computeProjectionMatrixFOV(camera.fov_deg, width / height, camera.near, camera.far)
    return np.asarray(projection, dtype=np.float64).reshape(4, 4).T
