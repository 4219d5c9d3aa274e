"""Depth images → world-frame points (pinhole back-projection), with checks that the depth is in metres.

``depth (H, W)`` float metres along the optical axis (0, NaN or inf: no return); ``intrinsics (3, 3)``;
``T_world_camera (4, 4)`` (OpenCV camera frame, ``perception.calibration``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.se3 import transform_points


class DepthUnitError(ValueError):
    """Depth values that cannot be metres (e.g. millimetres handed in as metres)."""


@dataclass(frozen=True)
class DepthRange:
    """Valid depth in metres: returns outside ``[near, far]`` are dropped. A frame whose median return lies
    beyond ``implausible`` metres is taken for a unit error (millimetres read as metres), not a scene."""

    near: float = 0.05
    far: float = 3.0
    implausible: float = 20.0


def check_depth_metres(depth: np.ndarray, depth_range: DepthRange, where: str) -> None:
    """Raise ``DepthUnitError`` when ``depth (H, W)`` is not a plausible metric depth image."""
    returns = depth[np.isfinite(depth) & (depth > 0)]
    if returns.size == 0:
        return
    median = float(np.median(returns))
    if median > depth_range.implausible:
        raise DepthUnitError(
            f"{where}: median depth {median:.1f} is not metres (more than {depth_range.implausible} m away): "
            f"depth in millimetres? Set the camera's depth_unit to 'mm' (values are multiplied by 0.001)"
        )
    if median < depth_range.near / 10:
        raise DepthUnitError(
            f"{where}: median depth {median:.4f} m is closer than any camera sees: depth already divided by 1000, "
            "or a disparity image?"
        )


def backproject(
    depth: np.ndarray, intrinsics: np.ndarray, T_world_camera: np.ndarray, depth_range: DepthRange
) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel of ``depth (H, W)`` metres as a world point.

    Returns ``points (H*W, 3)`` float32 in the world frame (row-major pixel order) and ``valid (H*W,)`` bool:
    pixels with a finite return within ``depth_range``.
    """
    height, width = depth.shape
    depth = np.asarray(depth, dtype=np.float64)
    valid = np.isfinite(depth) & (depth >= depth_range.near) & (depth <= depth_range.far)
    z = np.where(valid, depth, 0.0)
    rows, cols = np.mgrid[0:height, 0:width]
    x = (cols - intrinsics[0, 2]) / intrinsics[0, 0] * z
    y = (rows - intrinsics[1, 2]) / intrinsics[1, 1] * z
    camera_points = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    return transform_points(T_world_camera, camera_points).astype(np.float32), valid.reshape(-1)
