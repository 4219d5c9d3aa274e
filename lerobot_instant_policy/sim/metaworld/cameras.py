"""Segmented world-frame point clouds of a MetaWorld scene from MuJoCo's own depth and segmentation rendering.

Each camera renders two passes with ``mujoco.Renderer``: metric depth (MuJoCo turns the depth buffer into metres
along the optical axis with the model's ``vis.map.znear`` / ``zfar`` scaled by ``stat.extent``) and segmentation
(every pixel's object id and type). A pixel is kept when it shows a geom of a task object, or one of the task's
target sites (MetaWorld's goal markers, drawn as spheres in its own renders); it is dropped when it shows the
robot, MetaWorld's scenery (the table, the retaining wall, the floor: :mod:`.scenery` finds them in the model),
another site, or nothing. Kept pixels are back-projected
with the pinhole model of the camera's ``fovy`` (:mod:`...perception.depth`), fused over the cameras and resampled
to a fixed size (:mod:`...geometry.sampling`).

Frames: ``T_world_camera (4, 4)`` in the OpenCV convention (x right, y down, z along the optical axis), from the
camera's ``cam_xpos`` / ``cam_xmat`` in ``MjData`` (MuJoCo's cameras look along −z with y up), so cameras on the
hand (``behindGripper``) are placed where the hand is at the moment of rendering.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ...geometry.sampling import resample_points
from ...perception.depth import DepthRange, backproject

_GL_TO_OPENCV = np.diag([1.0, -1.0, -1.0])
_DEPTH_RANGE = DepthRange(near=0.01, far=5.0)
_GEOM = int(mujoco.mjtObj.mjOBJ_GEOM)  # plain ints: comparing arrays with the enum goes element by element
_SITE = int(mujoco.mjtObj.mjOBJ_SITE)


class EmptyCloudError(RuntimeError):
    """No camera saw a task object or target site."""


@dataclass(frozen=True)
class CameraSettings:
    """Which MetaWorld cameras render the cloud and at what resolution (square images, ``resolution`` pixels)."""

    cameras: tuple[str, ...] = ("corner2", "corner", "behindGripper")
    resolution: int = 320

    def __post_init__(self):
        if len(self.cameras) < 1 or self.resolution < 2:
            raise ValueError(f"need at least one camera and 2x2 pixels, got {self.cameras} at {self.resolution}")


def camera_intrinsics(model: mujoco.MjModel, camera: str, width: int, height: int) -> np.ndarray:
    """``K (3, 3)`` of ``camera`` rendered at ``width`` x ``height``: focal length from its vertical ``fovy``, the
    principal point at the image centre (OpenCV pixel convention: the first pixel's centre is (0, 0))."""
    fovy = np.deg2rad(model.cam(camera).fovy[0])
    focal = 0.5 * height / np.tan(0.5 * fovy)
    return np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def camera_pose(data: mujoco.MjData, camera: str) -> np.ndarray:
    """``T_world_camera (4, 4)`` of ``camera`` now, OpenCV axes (module docstring)."""
    T_world_camera = np.eye(4)
    T_world_camera[:3, :3] = data.cam(camera).xmat.reshape(3, 3) @ _GL_TO_OPENCV
    T_world_camera[:3, 3] = data.cam(camera).xpos
    return T_world_camera


class SegmentedDepthCameras:
    """Renders the segmented cloud of one MetaWorld model (module docstring).

    Args:
        model: the env's ``MjModel``.
        settings: cameras and resolution.
        task_geoms: ``(ngeom,)`` bool, the geoms kept (:func:`.scenery.task_object_geoms`).
        target_sites: names of the sites kept as goal markers (MetaWorld's ``_target_site_config``).
    """

    def __init__(self, model: mujoco.MjModel, settings: CameraSettings, task_geoms: np.ndarray,
                 target_sites: tuple[str, ...] = ()):
        for name in settings.cameras:
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name) < 0:
                known = [model.cam(index).name for index in range(model.ncam)]
                raise ValueError(f"MetaWorld has no camera {name!r}; its cameras are {known}")
        self.model = model
        self.settings = settings
        if task_geoms.shape != (model.ngeom,):
            raise ValueError(f"task_geoms must be ({model.ngeom},) bool, got {task_geoms.shape}")
        self.keep_geoms = task_geoms
        self.keep_sites = np.zeros(model.nsite, dtype=bool)
        for name in target_sites:
            self.keep_sites[model.site(name).id] = True
        size = settings.resolution
        self.intrinsics = {name: camera_intrinsics(model, name, size, size) for name in settings.cameras}
        self._renderer = mujoco.Renderer(model, size, size)

    def close(self) -> None:
        self._renderer.close()

    def render(self, data: mujoco.MjData) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per camera: ``depth (H, W)`` float32 metres and ``keep (H, W)`` bool (task object or target site)."""
        depths, masks = [], []
        for camera in self.settings.cameras:
            self._renderer.update_scene(data, camera=camera)
            self._renderer.enable_depth_rendering()
            depths.append(self._renderer.render().copy())
            self._renderer.disable_depth_rendering()
            self._renderer.enable_segmentation_rendering()
            segmentation = self._renderer.render()
            self._renderer.disable_segmentation_rendering()
            masks.append(self._kept(segmentation[..., 0], segmentation[..., 1]))
        return depths, masks

    def points(self, data: mujoco.MjData) -> np.ndarray:
        """The fused segmented cloud ``points_world (Q, 3)`` float32 of every kept pixel of every camera."""
        clouds = []
        for camera, depth, keep in zip(self.settings.cameras, *self.render(data), strict=True):
            points_world, valid = backproject(depth, self.intrinsics[camera], camera_pose(data, camera), _DEPTH_RANGE)
            clouds.append(points_world[valid & keep.reshape(-1)])
        return np.concatenate(clouds)

    def cloud(self, data: mujoco.MjData, num_points: int, rng: np.random.Generator) -> np.ndarray:
        """``points_world (num_points, 3)`` float32: :meth:`points` resampled (farthest-point sampling, or repeats
        when fewer). Raises :class:`EmptyCloudError` when no camera sees a task object."""
        points_world = self.points(data)
        if len(points_world) == 0:
            raise EmptyCloudError(f"no camera of {list(self.settings.cameras)} sees a task object or target site")
        return resample_points(points_world, num_points, rng)

    def _kept(self, object_ids: np.ndarray, object_types: np.ndarray) -> np.ndarray:
        """``(H, W)`` bool from a segmentation image's object ids and types (−1: background)."""
        geoms = (object_types == _GEOM) & (object_ids >= 0)
        sites = (object_types == _SITE) & (object_ids >= 0)
        keep = np.zeros(object_ids.shape, dtype=bool)
        keep[geoms] = self.keep_geoms[object_ids[geoms]]
        keep[sites] = self.keep_sites[object_ids[sites]]
        return keep
