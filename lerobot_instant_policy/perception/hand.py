"""A human hand as the parallel gripper (paper §4.3, appendix "Cross-embodiment transfer"; docs/design.md §10).

The observations hold no robot points, only the EE pose and the gripper state, so a hand stands in for the gripper
once its 21 landmarks (MediaPipe's layout: 0 wrist, 1-4 thumb CMC/MCP/IP/TIP, 5-8 index MCP/PIP/DIP/TIP, 9-12 middle,
13-16 ring, 17-20 pinky; world frame, metres) are mapped to ``T_world_ee (4, 4)`` and ``gripper_open`` in {0, 1}.
The EE frame is the gripper's (``geometry.gripper``): y along the fingers' opening, z the approach direction. Per
frame (:func:`ee_poses_from_landmarks`):

    position = midpoint of the thumb tip (4) and index tip (8), plus ``ee_offset_m`` (EE frame);
    EE y = unit vector thumb tip → index tip;
    EE z = the part of (fingertip midpoint − palm point) orthogonal to y, normalised: from the palm towards the
    fingertips, the way a gripper approaches; the palm point is the mean of ``palm_landmarks`` (wrist, index MCP,
    middle MCP: rigid points of the palm that neither the thumb nor the index's flexion moves);
    EE x = y × z (a proper rotation).

A frame is *missing* when a landmark it needs is NaN, when it is marked invalid, or when it is degenerate (the tips
closer than ``min_aperture_m``, so y is undefined, or the palm point within ``min_palm_offset_m`` of the thumb-index
axis, so z is undefined): no pose is computed from it. The gripper closes when the aperture |thumb tip − index tip|
falls below ``close_below_m`` and opens again above ``open_above_m`` (hysteresis), once the aperture has called for
the change on ``gripper_hold_frames`` found frames in a row (debounce); it starts open. A recorded episode goes
through :func:`map_hand_to_gripper`; a live stream through ``HandToGripperStateStep``. The hand is removed from
the segmented clouds by ``perception.hand_mask``; hand landmarks seen in an image are lifted to the world frame with
depth by :func:`lift_image_landmarks`.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
from lerobot.configs import FeatureType, PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry
from scipy.spatial.transform import Rotation

from ..contract import POSE_GRIPPER_SHAPE, STATE_KEY, vectors_from_poses
from ..geometry.se3 import slerp_rotations, transform_points
from .calibration import check_extrinsics, check_intrinsics
from .depth import DepthRange
from .steps import require

NUM_LANDMARKS = 21
WRIST, THUMB_TIP, INDEX_MCP, INDEX_TIP, MIDDLE_MCP = 0, 4, 5, 8, 9
HAND_LANDMARKS_KEY = "observation.hand_landmarks"
HAND_VALID_KEY = "observation.hand_valid"


class HandGapError(ValueError):
    """The hand is missing for more consecutive frames than ``max_gap_frames``, or was never seen."""


@dataclass
class HandMappingConfig:
    """How landmarks become the gripper (metres, EE frame).

    ``close_below_m`` / ``open_above_m``: the hysteresis of the gripper state on the thumb-index tip distance. MediaPipe
    puts the tip landmarks inside the fingertips, so touching tips read 1.5-2.5 cm and a pinched thin object about
    3 cm, while a released hand opens to 6-10 cm; the 1.5 cm band between the thresholds is several times the
    landmark noise (about 5 mm), so the state does not chatter. Raise both for a hand that pinches thick objects.
    ``palm_landmarks``: the landmarks averaged into the palm point that fixes the approach axis.
    ``ee_offset_m``: added to the fingertip midpoint, in the EE frame (e.g. ``(0, 0, -0.01)`` to put the EE origin
    1 cm back into the fingers).
    ``position_smoothing`` / ``rotation_smoothing``: the weight in [0, 1) of the previous filtered position / rotation
    in a causal exponential filter (rotation by SLERP); 0 turns it off, 0.5 halves the noise at a lag of one frame.
    ``gripper_hold_frames``: how many found frames in a row the aperture must call for a state change before the
    gripper changes (1: at once). Live the change then comes ``gripper_hold_frames - 1`` frames late; a recording
    dates it back (:func:`map_hand_to_gripper`). A single noisy frame crossing the band no longer opens a carrying
    pinch or closes a hand mid-air.
    ``max_gap_frames``: the most consecutive missing frames bridged (see :func:`map_hand_to_gripper`); a longer gap
    raises ``HandGapError``.
    ``min_aperture_m`` / ``min_palm_offset_m``: below these a frame is degenerate (missing).
    """

    close_below_m: float = 0.035
    open_above_m: float = 0.05
    palm_landmarks: tuple[int, ...] = (WRIST, INDEX_MCP, MIDDLE_MCP)
    ee_offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position_smoothing: float = 0.0
    rotation_smoothing: float = 0.0
    gripper_hold_frames: int = 2
    max_gap_frames: int = 3
    min_aperture_m: float = 0.002
    min_palm_offset_m: float = 0.01

    def __post_init__(self):
        self.palm_landmarks = tuple(int(index) for index in self.palm_landmarks)
        self.ee_offset_m = tuple(float(value) for value in self.ee_offset_m)
        if not 0 < self.min_aperture_m < self.close_below_m < self.open_above_m:
            raise ValueError(
                "need 0 < min_aperture_m < close_below_m < open_above_m (metres), got "
                f"{self.min_aperture_m}, {self.close_below_m}, {self.open_above_m}"
            )
        if not self.palm_landmarks or any(not 0 <= i < NUM_LANDMARKS for i in self.palm_landmarks):
            raise ValueError(f"palm_landmarks must be landmark ids in 0..20, got {self.palm_landmarks}")
        if THUMB_TIP in self.palm_landmarks or INDEX_TIP in self.palm_landmarks:
            raise ValueError(f"palm_landmarks must not hold the thumb or index tip (4, 8), got {self.palm_landmarks}")
        if len(self.ee_offset_m) != 3 or not np.all(np.isfinite(self.ee_offset_m)):
            raise ValueError(f"ee_offset_m must be 3 finite numbers (EE frame, m), got {self.ee_offset_m}")
        for name in ("position_smoothing", "rotation_smoothing"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"{name} must be in [0, 1) (0 = off), got {getattr(self, name)}")
        if self.gripper_hold_frames < 1 or int(self.gripper_hold_frames) != self.gripper_hold_frames:
            raise ValueError(f"gripper_hold_frames must be an integer >= 1 (1: off), got {self.gripper_hold_frames}")
        if self.max_gap_frames < 0 or int(self.max_gap_frames) != self.max_gap_frames:
            raise ValueError(f"max_gap_frames must be an integer >= 0, got {self.max_gap_frames}")
        if self.min_palm_offset_m <= 0:
            raise ValueError(f"min_palm_offset_m must be positive, got {self.min_palm_offset_m}")


def checked_landmarks(landmarks_world, ndim: int, shape_text: str, name: str = "landmarks_world") -> np.ndarray:
    """``landmarks_world`` as float64 numpy with ``ndim`` dimensions ending in ``(21, 3)``, or a ``ValueError``."""
    landmarks_world = np.asarray(landmarks_world, dtype=np.float64)
    if landmarks_world.ndim != ndim or landmarks_world.shape[-2:] != (NUM_LANDMARKS, 3):
        raise ValueError(
            f"{name} must have shape {shape_text} (MediaPipe's 21 hand landmarks, metres), got {landmarks_world.shape}"
        )
    return landmarks_world


def ee_poses_from_landmarks(landmarks_world: np.ndarray, config: HandMappingConfig) -> tuple[np.ndarray, ...]:
    """One frame at a time, no filtering: ``landmarks_world (..., 21, 3)`` → ``T_world_ee (..., 4, 4)`` (NaN where
    missing), ``aperture (...)`` m (thumb-index tip distance, NaN where missing) and ``found (...)`` bool."""
    landmarks_world = checked_landmarks(landmarks_world, max(np.ndim(landmarks_world), 2), "(..., 21, 3)")
    thumb, index = landmarks_world[..., THUMB_TIP, :], landmarks_world[..., INDEX_TIP, :]
    midpoint = (thumb + index) / 2
    palm = landmarks_world[..., list(config.palm_landmarks), :].mean(axis=-2)
    aperture = np.linalg.norm(index - thumb, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        y_axis = (index - thumb) / aperture[..., None]
        forward = midpoint - palm
        forward = forward - np.sum(forward * y_axis, axis=-1, keepdims=True) * y_axis
        palm_offset = np.linalg.norm(forward, axis=-1)
        z_axis = forward / palm_offset[..., None]
    found = (aperture >= config.min_aperture_m) & (palm_offset >= config.min_palm_offset_m)  # False for NaN
    rotation = np.stack([np.cross(y_axis, z_axis), y_axis, z_axis], axis=-1)
    T_world_ee = np.full((*found.shape, 4, 4), np.nan)
    T_world_ee[..., :3, :3] = rotation
    T_world_ee[..., :3, 3] = midpoint + rotation @ np.asarray(config.ee_offset_m)
    T_world_ee[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    T_world_ee[~found] = np.nan
    return T_world_ee, np.where(found, aperture, np.nan), found


class _HandFilter:
    """One stream's gripper hysteresis with its debounce, and pose smoothing (causal: each output depends on the
    frames so far)."""

    def __init__(self, config: HandMappingConfig):
        self.config = config
        self.T_world_ee: np.ndarray | None = None
        self.gripper_open = 1.0
        self.calls_for_change = 0  # found frames in a row whose aperture calls for the other state

    def update(self, T_measured: np.ndarray, aperture: float) -> tuple[np.ndarray, float]:
        """The filtered ``T_world_ee (4, 4)`` and gripper after ``T_measured (4, 4)`` and ``aperture`` (NaN: not
        measured: the gripper state and the debounce's count are held)."""
        if np.isfinite(aperture):
            called = 0.0 if aperture < self.config.close_below_m else 1.0 if aperture > self.config.open_above_m \
                else self.gripper_open
            self.calls_for_change = self.calls_for_change + 1 if called != self.gripper_open else 0
            if self.calls_for_change >= self.config.gripper_hold_frames:
                self.gripper_open, self.calls_for_change = called, 0
        if self.T_world_ee is None:
            self.T_world_ee = T_measured.copy()
        else:
            weight = self.config.position_smoothing
            position = weight * self.T_world_ee[:3, 3] + (1 - weight) * T_measured[:3, 3]
            fraction = np.array([1 - self.config.rotation_smoothing])
            self.T_world_ee[:3, :3] = slerp_rotations(self.T_world_ee[:3, :3], T_measured[:3, :3], fraction)[0]
            self.T_world_ee[:3, 3] = position
        return self.T_world_ee.copy(), self.gripper_open


@dataclass(frozen=True)
class HandTrajectory:
    """A hand demonstration as the gripper: ``T_world_ee (T, 4, 4)``, ``gripper_open (T,)`` float64 in {0, 1}, and
    ``valid (T,)`` bool: False on the frames bridged over a gap (their pose is interpolated, not measured)."""

    T_world_ee: np.ndarray
    gripper_open: np.ndarray
    valid: np.ndarray

    def state_vectors(self) -> np.ndarray:
        """``(T, 8)`` float64 in the data contract's layout (xyz, quaternion xyzw, gripper_open)."""
        return vectors_from_poses(self.T_world_ee, self.gripper_open)


def map_hand_to_gripper(
    landmarks_world, config: HandMappingConfig | None = None, valid: np.ndarray | None = None,
    window_frames: int = 1, aperture_window_frames: int = 1, dwell_frames: int = 1,
) -> HandTrajectory:
    """A recorded episode's ``landmarks_world (T, 21, 3)`` (``valid (T,)`` bool: False marks a frame missing) → its
    :class:`HandTrajectory`.

    With ``window_frames`` w > 1 (odd), each landmark of a valid frame is first replaced by its mean over the valid
    frames among the w centred on it that see it (:func:`centred_landmark_mean`): zero-phase smoothing, which a
    recording allows and a live stream cannot. Landmark noise of σ per coordinate gives the thumb-index axis an
    angular error of about √2·σ / aperture per frame (15-20° at σ = 1 cm and a 5-8 cm pinch) and the aperture a noise
    of √2·σ, enough to cross the hysteresis band; the mean over w frames divides both by up to √w, at the cost of
    blurring motion faster than w frames, above all at the turning points where the hand touches things (the mean of
    the frames around the lowest point of a push lies above it). With ``aperture_window_frames`` a > 1 (odd), the
    thumb-index aperture that sets the gripper state is then the median over the found frames among the a centred on
    each (:func:`centred_median`), the poses left as they are: the median keeps a steady close or release where it is
    (on a monotone run the centre is the median) and ignores a noisy frame or two. A run of at most
    ``max_gap_frames`` missing frames is bridged: between two found frames the position is interpolated linearly and
    the rotation by SLERP; before the first / after the last found frame the nearest found pose is held. The gripper
    state is held through a gap. A longer run raises ``HandGapError`` naming its frames (trim the recording to where
    the hand is in view). Hysteresis, its debounce and smoothing then run forward in time, as they do live; then, as
    a recording allows, each gripper change is dated back to the frame after the aperture last read the old state
    (above ``open_above_m`` before a close, below ``close_below_m`` before an open), never before the frame where the
    previous change was detected: a pinch changes when the fingers start to move, not when the aperture has crossed
    the band and held there (:func:`date_gripper_changes_back`). With ``dwell_frames`` d > 1 the hand is taken to hold
    still over the d frames from each change on, as a hand does while its fingers close or open, and their poses are
    replaced by their mean (:func:`hold_still_at_changes`): the pose a grasp or a release happens at, which a replay
    and a placement depend on, then carries up to √d times less landmark noise.
    """
    config = config or HandMappingConfig()
    landmarks_world = checked_landmarks(landmarks_world, 3, "(T, 21, 3)")
    if valid is None:
        valid = np.ones(len(landmarks_world), dtype=bool)
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != (len(landmarks_world),):
        raise ValueError(f"valid must have shape ({len(landmarks_world)},), one flag per frame, got {valid.shape}")
    if window_frames != 1:
        landmarks_world = centred_landmark_mean(landmarks_world, valid, window_frames)
    T_measured, aperture, found = ee_poses_from_landmarks(landmarks_world, config)
    found &= valid
    aperture = np.where(found, aperture, np.nan)
    if aperture_window_frames != 1:
        aperture = np.where(found, centred_median(aperture, aperture_window_frames), np.nan)
    if not found.any():
        raise HandGapError(f"no frame of the {len(found)} has a usable hand (missing, NaN or degenerate landmarks)")
    _bridge_gaps(T_measured, found, config.max_gap_frames)
    hand_filter = _HandFilter(config)
    filtered = [hand_filter.update(T_frame, width) for T_frame, width in zip(T_measured, aperture, strict=True)]
    gripper_open = date_gripper_changes_back(np.array([g for _, g in filtered]), aperture, config)
    T_world_ee = hold_still_at_changes(np.stack([T for T, _ in filtered]), gripper_open, found, dwell_frames)
    return HandTrajectory(T_world_ee, gripper_open, found)


def hold_still_at_changes(T_world_ee: np.ndarray, gripper_open: np.ndarray, found: np.ndarray,
                          dwell_frames: int) -> np.ndarray:
    """``T_world_ee (T, 4, 4)`` with the poses of the ``dwell_frames`` frames from each change of ``gripper_open (T,)``
    on (fewer where the next change or the end comes first) replaced by the mean of the ``found (T,)`` ones among
    them: positions averaged, rotations by their chordal mean (``scipy``'s ``Rotation.mean``). ``dwell_frames`` 1:
    unchanged."""
    check_dwell_frames(dwell_frames)
    T_world_ee = T_world_ee.copy()
    changes = np.flatnonzero(np.diff(gripper_open)) + 1
    ends = np.minimum(changes + dwell_frames, np.append(changes[1:], len(T_world_ee)))
    for change, end in zip(changes, ends, strict=True):
        span = np.arange(change, end)
        measured = span[found[span]]
        if len(measured) < 2:
            continue
        T_world_ee[span, :3, 3] = T_world_ee[measured, :3, 3].mean(axis=0)
        T_world_ee[span, :3, :3] = Rotation.from_matrix(T_world_ee[measured, :3, :3]).mean().as_matrix()
    return T_world_ee


def date_gripper_changes_back(gripper_open: np.ndarray, aperture: np.ndarray, config: HandMappingConfig) -> np.ndarray:
    """``gripper_open (T,)`` (the causal states of a recording) with each change moved back to the frame after the
    last one whose ``aperture (T,)`` m (NaN: missing) read the old state, and no earlier than the frame where the
    previous change was detected (which read the state it changed to)."""
    gripper_open = gripper_open.copy()
    with np.errstate(invalid="ignore"):
        reads_closed, reads_open = aperture < config.close_below_m, aperture > config.open_above_m
    previous = 0
    for change in np.flatnonzero(np.diff(gripper_open)) + 1:
        reads_old = reads_open if gripper_open[change] == 0.0 else reads_closed
        last_old = np.flatnonzero(reads_old[previous:change])
        start = previous + (last_old[-1] + 1 if len(last_old) else 0)
        gripper_open[start:change] = gripper_open[change]
        previous = change
    return gripper_open


def check_window(window_frames: int, name: str = "window_frames") -> None:
    """``ValueError`` unless ``window_frames`` (called ``name`` in the message) is an odd number >= 1 (a centred
    window; 1: off)."""
    if window_frames < 1 or window_frames % 2 == 0:
        raise ValueError(f"{name} must be an odd number >= 1 (1: off), got {window_frames}")


def check_dwell_frames(dwell_frames: int) -> None:
    """``ValueError`` unless ``dwell_frames`` is an integer >= 1 (1: off)."""
    if dwell_frames < 1 or int(dwell_frames) != dwell_frames:
        raise ValueError(f"dwell_frames must be an integer >= 1 (1: off), got {dwell_frames}")


def centred_median(values: np.ndarray, window_frames: int) -> np.ndarray:
    """``values (T,)`` with each replaced by the median of the finite ones among the ``window_frames`` (odd, positive)
    centred on it (fewer at the ends; NaN where none is finite)."""
    check_window(window_frames)
    half = window_frames // 2
    padded = np.concatenate([np.full(half, np.nan), values, np.full(half, np.nan)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN window: NaN
        return np.nanmedian(np.lib.stride_tricks.sliding_window_view(padded, window_frames), axis=-1)


def centred_landmark_mean(landmarks_world: np.ndarray, valid: np.ndarray, window_frames: int) -> np.ndarray:
    """``landmarks_world (T, 21, 3)`` with each finite landmark of a ``valid (T,)`` frame replaced by its mean over the
    valid frames among the ``window_frames`` (odd, positive) centred on it where it is finite (fewer at the ends); a
    missing (NaN) landmark, and every landmark of an invalid frame, stay as they were."""
    check_window(window_frames)
    seen = valid[:, None, None] & np.isfinite(landmarks_world)
    half, frames = window_frames // 2, len(landmarks_world)
    zero = np.zeros((1, *landmarks_world.shape[1:]))
    sums = np.concatenate([zero, np.cumsum(np.where(seen, landmarks_world, 0.0), axis=0)])
    counts = np.concatenate([zero, np.cumsum(seen, axis=0, dtype=np.float64)])
    low, high = np.clip(np.arange(frames) - half, 0, frames), np.clip(np.arange(frames) + half + 1, 0, frames)
    means = (sums[high] - sums[low]) / np.maximum(counts[high] - counts[low], 1.0)
    return np.where(seen, means, landmarks_world)


def _bridge_gaps(T_world_ee: np.ndarray, found: np.ndarray, max_gap_frames: int) -> None:
    """Fill the missing frames of ``T_world_ee (T, 4, 4)`` in place as :func:`map_hand_to_gripper` says."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (~found).astype(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start > max_gap_frames:
            raise HandGapError(
                f"the hand is missing in frames {start}..{stop - 1} ({stop - start} frames; max_gap_frames="
                f"{max_gap_frames})"
            )
        before, after = (start - 1 if start > 0 else stop), (stop if stop < len(found) else start - 1)
        fractions = (np.arange(start, stop) - before) / (after - before) if after != before else np.zeros(stop - start)
        T_before, T_after = T_world_ee[before], T_world_ee[after]  # found frames, outside the gap
        T_world_ee[start:stop] = np.eye(4)
        T_world_ee[start:stop, :3, 3] = (1 - fractions[:, None]) * T_before[:3, 3] + fractions[:, None] * T_after[:3, 3]
        T_world_ee[start:stop, :3, :3] = slerp_rotations(T_before[:3, :3], T_after[:3, :3], fractions)


@ProcessorStepRegistry.register(name="ip_hand_to_gripper_state")
@dataclass
class HandToGripperStateStep(ObservationProcessorStep):
    """``hand_landmarks (B, 21, 3)`` (world frame, m) → ``state (B, 8)`` float32 (the data contract's EE pose and
    gripper) and ``hand_valid (B,)`` bool, live: each batch row is one stream (one camera rig or env) whose frames
    come in successive calls, filtered causally (hysteresis, smoothing) until ``reset()``.

    A missing frame holds the row's last output with ``hand_valid`` False, for at most ``max_gap_frames`` frames in a
    row; a longer gap, or a missing frame before the row's first found one, raises ``HandGapError``. The filter state
    belongs to one episode, so it is not in ``state_dict`` (saved with the pipeline) but cleared by ``reset()``.
    """

    config: HandMappingConfig = field(default_factory=HandMappingConfig)

    def __post_init__(self):
        if isinstance(self.config, dict):
            self.config = HandMappingConfig(**self.config)
        self.reset()

    def reset(self) -> None:
        self._filters: list[_HandFilter] | None = None
        self._gap_frames: np.ndarray | None = None

    def observation(self, observation: dict) -> dict:
        step = type(self).__name__
        landmarks = require(observation, HAND_LANDMARKS_KEY, step, 3, "(B, 21, 3)")
        landmarks = checked_landmarks(landmarks, 3, "(B, 21, 3)", name=HAND_LANDMARKS_KEY)
        T_measured, aperture, found = ee_poses_from_landmarks(landmarks, self.config)
        if self._filters is None:
            self._filters = [_HandFilter(self.config) for _ in range(len(found))]
            self._gap_frames = np.zeros(len(found), dtype=int)
        if len(self._filters) != len(found):
            raise ValueError(f"{step}: {len(found)} rows, but this stream has {len(self._filters)}; reset() first")
        T_world_ee, gripper_open = np.empty_like(T_measured), np.empty(len(found))
        for row, hand_filter in enumerate(self._filters):
            if found[row]:
                self._gap_frames[row] = 0
                T_world_ee[row], gripper_open[row] = hand_filter.update(T_measured[row], aperture[row])
                continue
            self._gap_frames[row] += 1
            if hand_filter.T_world_ee is None or self._gap_frames[row] > self.config.max_gap_frames:
                raise HandGapError(
                    f"{step}: no usable hand in row {row} for {self._gap_frames[row]} frame(s) "
                    f"({'none found yet' if hand_filter.T_world_ee is None else 'max_gap_frames exceeded'})"
                )
            T_world_ee[row], gripper_open[row] = hand_filter.T_world_ee, hand_filter.gripper_open
        state = torch.from_numpy(vectors_from_poses(T_world_ee, gripper_open).astype(np.float32))
        return {**observation, STATE_KEY: state, HAND_VALID_KEY: torch.from_numpy(found)}

    def get_config(self) -> dict[str, Any]:
        return {"config": asdict(self.config)}

    def transform_features(self, features):
        observation = dict(features.get(PipelineFeatureType.OBSERVATION, {}))
        observation[STATE_KEY] = PolicyFeature(type=FeatureType.STATE, shape=POSE_GRIPPER_SHAPE)
        return {**features, PipelineFeatureType.OBSERVATION: observation}


def lift_image_landmarks(
    landmarks_px, depth, intrinsics, T_world_camera, window_px: int = 2, depth_range: DepthRange | None = None
) -> np.ndarray:
    """Image landmarks ``landmarks_px (T, 21, 2)`` (pixels ``(u, v)`` = (column, row), OpenCV convention; MediaPipe's
    normalised image landmarks times the image width and height) with ``depth (T, H, W)`` metres, ``intrinsics (3, 3)``
    and ``T_world_camera (4, 4)`` (``perception.calibration``) → ``landmarks_world (T, 21, 3)``.

    Each landmark's depth is the median of the valid returns (finite, within ``depth_range``) in the
    ``(2 window_px + 1)²`` pixels around it, robust to a missing pixel and to the background at a finger's edge; a
    landmark outside the image, or with no valid return around it, is NaN (its frame is then missing if the mapping
    needs it). The whole-image ``depth.backproject`` does not fit: here 21 sub-pixel points are lifted per frame.
    """
    landmarks_px, depth = np.asarray(landmarks_px, dtype=np.float64), np.asarray(depth, dtype=np.float64)
    if landmarks_px.ndim != 3 or landmarks_px.shape[1:] != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks_px must have shape (T, 21, 2) (pixels u, v), got {landmarks_px.shape}")
    if depth.ndim != 3 or len(depth) != len(landmarks_px):
        raise ValueError(f"depth must have shape ({len(landmarks_px)}, H, W) metres, got {depth.shape}")
    if window_px < 0:
        raise ValueError(f"window_px must be >= 0, got {window_px}")
    frames, height, width = depth.shape
    check_intrinsics(intrinsics, width, height, "hand camera")
    check_extrinsics(T_world_camera, "hand camera")
    depth_range = depth_range or DepthRange()
    with np.errstate(invalid="ignore"):
        centre = np.round(landmarks_px).astype(np.int64)  # NaN pixels become garbage, masked by `inside` below
    inside = np.all(np.isfinite(landmarks_px), axis=-1) & (centre[..., 0] >= 0) & (centre[..., 0] < width)
    inside &= (centre[..., 1] >= 0) & (centre[..., 1] < height)
    offsets = np.arange(-window_px, window_px + 1)
    cols = centre[..., 0, None, None] + offsets[None, :]
    rows = centre[..., 1, None, None] + offsets[:, None]
    in_image = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height) & inside[..., None, None]
    window = depth[np.arange(frames)[:, None, None, None], rows.clip(0, height - 1), cols.clip(0, width - 1)]
    window = np.where(in_image & (window >= depth_range.near) & (window <= depth_range.far), window, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows: no return, the landmark is NaN
        z = np.nanmedian(window.reshape(frames, NUM_LANDMARKS, -1), axis=-1)
    intrinsics = np.asarray(intrinsics, dtype=np.float64)
    x = (landmarks_px[..., 0] - intrinsics[0, 2]) / intrinsics[0, 0] * z
    y = (landmarks_px[..., 1] - intrinsics[1, 2]) / intrinsics[1, 1] * z
    camera_points = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    T_world_camera = np.asarray(T_world_camera, dtype=np.float64)
    return transform_points(T_world_camera, camera_points).reshape(frames, NUM_LANDMARKS, 3)


# A right hand pinching, in the EE frame at aperture 0 (metres): the thumb (x = 0, y < 0) and index (y > 0) reach the
# EE origin, the middle, ring and pinky fingers curl beside them, the palm lies behind along -z. The tips' y is
# moved to ±aperture/2 and the thumb's and index's IP/DIP joints with them.
_PINCH_HAND_EE = np.array([
    (0.0, 0.01, -0.13),
    (0.0, -0.02, -0.11), (0.0, -0.035, -0.075), (0.0, -0.015, -0.035), (0.0, 0.0, 0.0),
    (-0.01, 0.03, -0.06), (-0.005, 0.03, -0.03), (0.0, 0.015, -0.01), (0.0, 0.0, 0.0),
    (0.01, 0.035, -0.065), (0.015, 0.06, -0.04), (0.015, 0.055, -0.02), (0.015, 0.045, -0.01),
    (0.03, 0.035, -0.07), (0.035, 0.055, -0.05), (0.035, 0.05, -0.03), (0.035, 0.04, -0.025),
    (0.045, 0.03, -0.08), (0.05, 0.045, -0.065), (0.05, 0.04, -0.05), (0.05, 0.035, -0.045),
])
_OPENING_SIDE = np.zeros(NUM_LANDMARKS)
_OPENING_SIDE[[3, 4]], _OPENING_SIDE[[6, 7, 8]] = -1.0, 1.0


def landmarks_from_gripper(
    T_world_ee, aperture_m, rng: np.random.Generator | None = None, noise_m: float = 0.0
) -> np.ndarray:
    """A plausible pinching hand for gripper poses: ``T_world_ee (4, 4)`` or ``(T, 4, 4)`` and ``aperture_m`` (a
    number or ``(T,)``) → ``landmarks_world (21, 3)`` or ``(T, 21, 3)``, whose thumb and index tips lie on the EE y
    axis at ∓aperture/2 and whose palm lies behind along -z (what :func:`map_hand_to_gripper` inverts with the
    default config), plus Gaussian noise of ``noise_m`` per coordinate (a simulated detector)."""
    T_world_ee = np.asarray(T_world_ee, dtype=np.float64)
    if T_world_ee.shape[-2:] != (4, 4) or T_world_ee.ndim not in (2, 3):
        raise ValueError(f"T_world_ee must have shape (4, 4) or (T, 4, 4), got {T_world_ee.shape}")
    poses = T_world_ee.reshape(-1, 4, 4)
    aperture = np.broadcast_to(np.asarray(aperture_m, dtype=np.float64), (len(poses),))
    hand_ee = np.repeat(_PINCH_HAND_EE[None], len(poses), axis=0)
    hand_ee[..., 1] += _OPENING_SIDE * aperture[:, None] / 2
    landmarks = hand_ee @ np.swapaxes(poses[:, :3, :3], -1, -2) + poses[:, None, :3, 3]
    if noise_m > 0:
        landmarks += (rng or np.random.default_rng()).normal(0.0, noise_m, landmarks.shape)
    return landmarks.reshape(*T_world_ee.shape[:-2], NUM_LANDMARKS, 3)
