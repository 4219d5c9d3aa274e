"""Camera calibration: pinhole intrinsics and the camera-to-world pose of each depth camera, checked on load.

Conventions (the same as OpenCV and ROS ``*_optical_frame``): the camera frame has x to the right of the image,
y down and z along the optical axis; pixel ``(u, v)`` is (column, row) with the centre of the first pixel at
``(0, 0)``; ``T_world_camera (4, 4)`` maps points in the camera frame to the world frame (the robot base frame
on a real robot), metres.

The calibration file a user writes once is JSON (``docs/deployment.md``)::

    {"cameras": [
      {"name": "front", "depth_key": "observation.images.front_depth", "width": 640, "height": 480,
       "fx": 615.0, "fy": 615.0, "cx": 319.5, "cy": 239.5, "depth_unit": "mm",
       "T_world_camera": [[...4 numbers...], [...], [...], [0, 0, 0, 1]],
       "mask_key": null}
    ]}

A dataset can carry the same per-camera entry (without ``name`` / ``depth_key``) in its depth feature's ``info``
under ``"camera_calibration"`` (``meta/info.json``); ``calibration_from_dataset_features`` reads it from there.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

DEPTH_UNITS = {"m": 1.0, "mm": 0.001}
CALIBRATION_INFO_KEY = "camera_calibration"


class CalibrationError(ValueError):
    """Camera intrinsics or extrinsics are missing, malformed or inconsistent with the images."""


@dataclass(frozen=True)
class CameraCalibration:
    """One depth camera.

    ``fx, fy, cx, cy``: pinhole intrinsics in pixels (OpenCV convention); ``width, height``: image size in pixels;
    ``T_world_camera``: ``(4, 4)`` nested lists, camera (optical) frame → world frame, metres;
    ``depth_unit``: ``"m"`` or ``"mm"``, the unit of the stored depth values;
    ``depth_key``: the observation/dataset key of this camera's depth image;
    ``mask_key``: optional key of a per-pixel object mask (nonzero = task object) of the same size.
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    T_world_camera: tuple[tuple[float, ...], ...]
    depth_key: str = ""
    depth_unit: str = "m"
    mask_key: str | None = None

    def __post_init__(self):
        where = f"camera {self.name!r}"
        if self.width <= 0 or self.height <= 0:
            raise CalibrationError(f"{where}: width and height must be positive, got {self.width}x{self.height}")
        check_intrinsics(self.intrinsics, self.width, self.height, where)
        check_extrinsics(self.pose, where)
        if self.depth_unit not in DEPTH_UNITS:
            raise CalibrationError(f"{where}: depth_unit must be one of {sorted(DEPTH_UNITS)}, got {self.depth_unit!r}")

    @property
    def intrinsics(self) -> np.ndarray:
        """``K (3, 3)`` float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def pose(self) -> np.ndarray:
        """``T_world_camera (4, 4)`` float64."""
        return np.asarray(self.T_world_camera, dtype=np.float64)

    @property
    def metres_per_unit(self) -> float:
        return DEPTH_UNITS[self.depth_unit]

    def to_dict(self) -> dict:
        entry = asdict(self)
        entry["T_world_camera"] = [list(row) for row in self.T_world_camera]
        return entry

    @classmethod
    def from_dict(cls, entry: dict, where: str = "calibration") -> CameraCalibration:
        """A camera from its JSON entry; ``CalibrationError`` names missing or unknown fields."""
        required = ("width", "height", "fx", "fy", "cx", "cy", "T_world_camera")
        missing = [key for key in required if entry.get(key) is None]
        if missing:
            raise CalibrationError(f"{where}: camera {entry.get('name', '?')!r} lacks {missing}")
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(entry) - known)
        if unknown:
            raise CalibrationError(f"{where}: unknown camera fields {unknown}; expected some of {sorted(known)}")
        pose = np.asarray(entry["T_world_camera"], dtype=np.float64)
        if pose.shape != (4, 4):
            raise CalibrationError(f"{where}: T_world_camera must be 4x4, got shape {pose.shape}")
        values = {**entry, "T_world_camera": tuple(tuple(float(x) for x in row) for row in pose)}
        values.setdefault("name", entry.get("depth_key", "camera"))
        return cls(**values)


def check_intrinsics(intrinsics: np.ndarray, width: int, height: int, where: str) -> None:
    """Raise ``CalibrationError`` unless ``intrinsics (3, 3)`` is a finite pinhole matrix whose focal lengths are
    positive and whose principal point lies inside a ``width`` x ``height`` image."""
    intrinsics = np.asarray(intrinsics, dtype=np.float64)
    if intrinsics.shape != (3, 3) or not np.all(np.isfinite(intrinsics)):
        raise CalibrationError(f"{where}: intrinsics must be a finite 3x3 matrix, got {intrinsics.tolist()}")
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    if fx <= 0 or fy <= 0:
        raise CalibrationError(f"{where}: focal lengths must be positive, got fx={fx}, fy={fy}")
    if not (0 <= cx < width and 0 <= cy < height):
        raise CalibrationError(
            f"{where}: principal point ({cx}, {cy}) lies outside the {width}x{height} image: intrinsics for another "
            "resolution, or width and height swapped?"
        )
    if not np.allclose(intrinsics[2], [0.0, 0.0, 1.0]) or intrinsics[1, 0] != 0:
        raise CalibrationError(f"{where}: not a pinhole matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]: {intrinsics.tolist()}")


def check_extrinsics(pose: np.ndarray, where: str) -> None:
    """Raise ``CalibrationError`` unless ``pose (4, 4)`` is a finite rigid transform (rotation orthonormal with
    determinant +1, last row 0 0 0 1, translation within 10 m: metres, not millimetres)."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise CalibrationError(f"{where}: T_world_camera must be a finite 4x4 matrix, got shape {pose.shape}")
    rotation = pose[:3, :3]
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise CalibrationError(f"{where}: T_world_camera's last row must be [0, 0, 0, 1], got {pose[3].tolist()}")
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-3) or np.linalg.det(rotation) < 0:
        raise CalibrationError(
            f"{where}: T_world_camera's rotation is not a rotation (orthonormal, det +1; det = "
            f"{np.linalg.det(rotation):.3f}): a transposed, scaled or mirrored matrix?"
        )
    if np.linalg.norm(pose[:3, 3]) > 10.0:
        raise CalibrationError(
            f"{where}: camera is {np.linalg.norm(pose[:3, 3]):.1f} m from the world origin: translation in millimetres?"
        )


def load_calibration(path: str | Path) -> list[CameraCalibration]:
    """The cameras of a calibration JSON file (format in the module docstring), each checked."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"calibration file {path} does not exist")
    try:
        document = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise CalibrationError(f"calibration file {path} is not valid JSON: {error}") from error
    cameras = document.get("cameras") if isinstance(document, dict) else None
    if not cameras:
        raise CalibrationError(f"calibration file {path} has no non-empty 'cameras' list")
    calibration = [CameraCalibration.from_dict(entry, where=str(path)) for entry in cameras]
    for camera in calibration:
        if not camera.depth_key:
            raise CalibrationError(f"{path}: camera {camera.name!r} has no depth_key (the dataset key of its depth)")
    return calibration


def save_calibration(cameras: list[CameraCalibration], path: str | Path) -> None:
    Path(path).write_text(json.dumps({"cameras": [camera.to_dict() for camera in cameras]}, indent=2) + "\n")


def calibration_from_dataset_features(features: dict[str, dict]) -> list[CameraCalibration]:
    """The cameras recorded in a LeRobot dataset's metadata: every depth feature (``info.is_depth_map``) with a
    ``camera_calibration`` entry in its ``info``; ``CalibrationError`` when a depth feature has none."""
    cameras, uncalibrated = [], []
    for key, feature in features.items():
        info = feature.get("info") or {}
        if not info.get("is_depth_map"):
            continue
        entry = info.get(CALIBRATION_INFO_KEY)
        if entry is None:
            uncalibrated.append(key)
            continue
        entry = {**entry, "depth_key": key, "name": entry.get("name", key)}
        cameras.append(CameraCalibration.from_dict(entry, where=f"dataset feature {key!r}"))
    if uncalibrated or not cameras:
        raise CalibrationError(
            f"the dataset's depth features {uncalibrated or '(none)'} carry no '{CALIBRATION_INFO_KEY}' in their info: "
            "pass a calibration file (--calibration, format in docs/deployment.md)"
        )
    return cameras
