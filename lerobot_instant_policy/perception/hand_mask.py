"""Removing a demonstrator's hand from the segmented clouds: the hand must not reach an object cloud, where the robot
would read it as part of an object (docs/design.md §10).

Two ways, as LeRobot ``ProcessorStep``s between ``DepthToPointCloudStep`` and ``ResamplePointCloudStep`` (they clear
``pointcloud_mask`` like the other segmentation steps of ``perception.steps``):

    ``MaskHandPointsStep``: by the hand's world-frame landmarks ``hand_landmarks (B, 21, 3)`` (:func:`mask_hand_points`,
    the skeleton thickened to a volume);
    ``ClearHandPixelsStep``: by a per-pixel hand mask ``hand_mask (B, C, H, W)`` of a detector (nonzero = hand), where
    the fused cloud still has one point per pixel.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from lerobot.configs import PipelineFeatureType
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry
from scipy.ndimage import binary_dilation

from ..contract import POINTCLOUD_KEY
from .hand import HAND_LANDMARKS_KEY, checked_landmarks
from .steps import CLOUD_MASK_KEY, CloudSegmentationStep, require

HAND_MASK_KEY = "observation.hand_mask"

# MediaPipe's HAND_CONNECTIONS: the palm outline, then the thumb, index, middle, ring and pinky bones.
HAND_BONES: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 5), (5, 9), (9, 13), (13, 17), (0, 17),
    (1, 2), (2, 3), (3, 4), (5, 6), (6, 7), (7, 8), (9, 10), (10, 11), (11, 12),
    (13, 14), (14, 15), (15, 16), (17, 18), (18, 19), (19, 20),
)
# The palm polygon 0-1-5-9-13-17 as a fan of triangles from the wrist, and the fan's edges that are not bones.
PALM_TRIANGLES: tuple[tuple[int, int, int], ...] = ((0, 1, 5), (0, 5, 9), (0, 9, 13), (0, 13, 17))
_PALM_EDGES = ((1, 5), (0, 9), (0, 13))


def mask_hand_points(points_world, landmarks_world, radius_m: float) -> np.ndarray:
    """``keep`` bool, ``(P,)`` for ``points_world (P, 3)`` and ``landmarks_world (21, 3)``, or ``(B, P)`` for
    ``(B, P, 3)`` and ``(B, 21, 3)`` (world frame, m): False for every point within ``radius_m`` of the hand, i.e. of a
    bone (a capsule around each of :data:`HAND_BONES`) or of the palm (the slab of that half-thickness over
    :data:`PALM_TRIANGLES`).

    A hand whose landmarks are all NaN (none in view) removes nothing; one with only some NaN raises ``ValueError``,
    since the volume of its missing bones is unknown (use ``ClearHandPixelsStep`` with a detector's mask then).
    """
    points_world = np.asarray(points_world, dtype=np.float64)
    if points_world.ndim == 3:
        landmarks_world = checked_landmarks(landmarks_world, 3, f"({len(points_world)}, 21, 3)")
        if len(landmarks_world) != len(points_world):
            raise ValueError(f"{len(points_world)} clouds but {len(landmarks_world)} hands; need one hand per cloud")
        return np.stack([mask_hand_points(p, h, radius_m) for p, h in zip(points_world, landmarks_world, strict=True)])
    if points_world.ndim != 2 or points_world.shape[1] != 3:
        raise ValueError(f"points_world must have shape (P, 3) or (B, P, 3), got {points_world.shape}")
    landmarks_world = checked_landmarks(landmarks_world, 2, "(21, 3)")
    if radius_m <= 0:
        raise ValueError(f"radius_m must be positive, got {radius_m}")
    missing = ~np.all(np.isfinite(landmarks_world), axis=1)
    if missing.all():
        return np.ones(len(points_world), dtype=bool)
    if missing.any():
        raise ValueError(f"hand landmarks {np.flatnonzero(missing).tolist()} are NaN: the hand's volume is unknown")
    keep = np.ones(len(points_world), dtype=bool)
    near = np.flatnonzero(np.all((points_world >= landmarks_world.min(axis=0) - radius_m)
                                 & (points_world <= landmarks_world.max(axis=0) + radius_m), axis=1))
    points = points_world[near]
    inside = np.zeros(len(points), dtype=bool)
    for first, second in HAND_BONES + _PALM_EDGES:
        start, bone = landmarks_world[first], landmarks_world[second] - landmarks_world[first]
        along = np.clip((points - start) @ bone / max(bone @ bone, 1e-12), 0.0, 1.0)
        inside |= np.linalg.norm(points - start - along[:, None] * bone, axis=1) <= radius_m
    for corners in PALM_TRIANGLES:
        inside |= _within_triangle_slab(points, landmarks_world[list(corners)], radius_m)
    keep[near[inside]] = False
    return keep


def _within_triangle_slab(points: np.ndarray, corners: np.ndarray, half_thickness: float) -> np.ndarray:
    """``(P,)`` True for ``points (P, 3)`` that project inside the triangle ``corners (3, 3)`` and lie within
    ``half_thickness`` of its plane (a degenerate triangle has no slab: its edges are capsules)."""
    edge_1, edge_2 = corners[1] - corners[0], corners[2] - corners[0]
    normal = np.cross(edge_1, edge_2)
    area_2 = np.linalg.norm(normal)
    if area_2 < 1e-12:
        return np.zeros(len(points), dtype=bool)
    relative = points - corners[0]
    # Barycentric coordinates of the projection onto the plane (Cramer's rule on the edge Gram matrix).
    d11, d12, d22 = edge_1 @ edge_1, edge_1 @ edge_2, edge_2 @ edge_2
    r1, r2 = relative @ edge_1, relative @ edge_2
    u = (d22 * r1 - d12 * r2) / (area_2 ** 2)
    v = (d11 * r2 - d12 * r1) / (area_2 ** 2)
    return (u >= 0) & (v >= 0) & (u + v <= 1) & (np.abs(relative @ normal) / area_2 <= half_thickness)


@ProcessorStepRegistry.register(name="ip_mask_hand_points")
@dataclass
class MaskHandPointsStep(CloudSegmentationStep):
    """Remove the points within ``radius_m`` of the hand posed by ``hand_landmarks (B, 21, 3)`` (world frame, m;
    :func:`mask_hand_points`). The default is a finger's half-thickness (about 1 cm) plus the landmarks' noise."""

    radius_m: float = 0.015
    landmarks_key: str = HAND_LANDMARKS_KEY

    def keep(self, points, observation, row):
        landmarks = require(observation, self.landmarks_key, type(self).__name__, 3, "(B, 21, 3)")
        return mask_hand_points(points, landmarks[row], self.radius_m)


@ProcessorStepRegistry.register(name="ip_clear_hand_pixels")
@dataclass
class ClearHandPixelsStep(ObservationProcessorStep):
    """Clear ``pointcloud_mask (B, C*H*W)`` at the pixels of ``hand_mask (B, C, H, W)`` (nonzero = hand), grown by
    ``dilate_px`` pixels (a detector's mask misses the hand's rim, where depth still sees it), and drop
    ``hand_mask``. It runs where the fused cloud has one point per pixel: after ``DepthToPointCloudStep``, before
    ``ResamplePointCloudStep``."""

    dilate_px: int = 2

    def observation(self, observation: dict) -> dict:
        step = type(self).__name__
        hand = require(observation, HAND_MASK_KEY, step, 4, "(B, C, H, W)") != 0
        require(observation, POINTCLOUD_KEY, step, 3, "(B, C*H*W, 3)")
        mask = require(observation, CLOUD_MASK_KEY, step, 2, "(B, C*H*W)").astype(bool)
        if mask.shape != (len(hand), hand[0].size):
            raise ValueError(
                f"{step}: hand_mask {hand.shape} does not match pointcloud_mask {mask.shape}: run it after "
                "DepthToPointCloudStep, before the cloud is resampled"
            )
        if self.dilate_px > 0:
            width = 2 * self.dilate_px + 1
            hand = binary_dilation(hand, structure=np.ones((1, 1, width, width), dtype=bool))
        kept = {key: value for key, value in observation.items() if key != HAND_MASK_KEY}
        return {**kept, CLOUD_MASK_KEY: mask & ~hand.reshape(len(hand), -1)}

    def get_config(self) -> dict[str, Any]:
        return {"dilate_px": self.dilate_px}

    def transform_features(self, features):
        observation = {key: value for key, value in features.get(PipelineFeatureType.OBSERVATION, {}).items()
                       if key != HAND_MASK_KEY}
        return {**features, PipelineFeatureType.OBSERVATION: observation}
