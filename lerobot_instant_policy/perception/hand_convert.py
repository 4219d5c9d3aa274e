"""Hand recordings (``perception.hand_recording``) → a LeRobot dataset of demonstrations in the data contract
(``lerobot-ip-convert-hand``).

Per recording (one episode):

1. the hand's world landmarks ``(T, 21, 3)``: given (``landmarks`` "world"), or the detector's image landmarks lifted
   with the hand camera's depth and calibration (``hand.lift_image_landmarks``, frame by frame since a camera may
   move); a frame whose ``hand_score`` is below ``min_hand_score``, or whose ``handedness`` is not ``hand`` (when
   set), counts as missing;
2. the gripper: ``hand.map_hand_to_gripper`` (the landmarks averaged over a centred window of ``window_frames``,
   then EE pose, gripper state with hysteresis on the aperture's centred median of ``aperture_window_frames``, the
   poses of the ``dwell_frames`` from each gripper change averaged (the hand holds still while its fingers close or
   open), gaps of at most ``mapping.max_gap_frames`` bridged and marked; a longer gap raises ``HandGapError`` naming
   the recording and its frames);
3. the clouds: every camera's depth back-projected and fused, the hand removed — its pixels (``hand_mask``, when the
   recording has one, grown by ``hand_mask_dilate_px`` for a detector's mask, ``ClearHandPixelsStep``) and everything
   within ``hand_radius_m`` of its skeleton (``MaskHandPointsStep``; on a frame where a landmark is missing, that
   landmark interpolated in time from the frames that have it) — then the workspace crop, the segmentation and
   resampling to ``num_points`` (``perception.steps``). The segmentation is the recording's ``object_mask`` when it
   has one (a segmenter's task-object pixels: a flat target, a marker on the table, stays), else everything more
   than a few millimetres above the table plane;
4. ``observation.state`` the mapped EE pose and gripper, ``action`` the next frame's (the last frame's repeated).

Every recording is loaded, checked and mapped before anything is written; a failure while writing removes the
partial output. The bridged frames of each episode are listed in ``OUT/meta/hand_frames.json``.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from lerobot.processor import PolicyProcessorPipeline

from ..contract import POINTCLOUD_KEY
from .hand import (
    HAND_LANDMARKS_KEY,
    HandGapError,
    HandMappingConfig,
    HandTrajectory,
    check_dwell_frames,
    check_window,
    lift_image_landmarks,
    map_hand_to_gripper,
)
from .hand_mask import HAND_MASK_KEY, ClearHandPixelsStep, MaskHandPointsStep
from .hand_recording import HandRecording, find_hand_recordings, load_hand_recording
from .steps import (
    DEPTH_KEY,
    EXTRINSICS_KEY,
    INTRINSICS_KEY,
    OBJECT_MASK_KEY,
    CropWorkspaceStep,
    DepthToPointCloudStep,
    RemoveTablePlaneStep,
    ResamplePointCloudStep,
)

HAND_FRAMES_FILE = "hand_frames.json"  # in OUT/meta: per episode, its recording and bridged frames


class HandConversionError(ValueError):
    """A hand recording that cannot become a demonstration (the message names the recording)."""


@dataclass
class HandConvertSettings:
    """What :func:`convert_hand_recordings` reads and how (module docstring; workspace corners in metres, world)."""

    recordings: Path
    out: Path
    repo_id: str
    mapping: HandMappingConfig = field(default_factory=HandMappingConfig)
    window_frames: int = 1
    aperture_window_frames: int = 5
    dwell_frames: int = 1
    num_points: int = 2048
    hand_radius_m: float = 0.015
    hand_mask_dilate_px: int = 2
    min_hand_score: float = 0.5
    hand: str | None = None
    window_px: int = 2
    workspace_low: tuple[float, float, float] = (0.15, -0.5, -0.05)
    workspace_high: tuple[float, float, float] = (0.85, 0.5, 0.6)
    overwrite: bool = False

    def __post_init__(self):
        if self.hand not in (None, "Left", "Right"):
            raise HandConversionError(f"hand must be 'Left', 'Right' or None (either), got {self.hand!r}")
        if not 0.0 <= self.min_hand_score <= 1.0:
            raise HandConversionError(f"min_hand_score must be in [0, 1], got {self.min_hand_score}")
        if self.hand_radius_m <= 0 or self.num_points <= 0:
            raise HandConversionError("hand_radius_m and num_points must be positive")
        try:  # the mapping's own checks, before any recording is read
            check_window(self.window_frames, "window_frames")
            check_window(self.aperture_window_frames, "aperture_window_frames")
            check_dwell_frames(self.dwell_frames)
        except ValueError as error:
            raise HandConversionError(str(error)) from error
        if self.hand_mask_dilate_px < 0:
            raise HandConversionError(f"hand_mask_dilate_px must be non-negative, got {self.hand_mask_dilate_px}")


@dataclass(frozen=True)
class HandEpisode:
    """One recording mapped: its ``landmarks_world (T, 21, 3)`` (NaN where missing) and :class:`HandTrajectory`."""

    recording: HandRecording
    landmarks_world: np.ndarray
    trajectory: HandTrajectory


def map_recording(recording: HandRecording, settings: HandConvertSettings) -> HandEpisode:
    """Steps 1 and 2 of the module docstring for one recording."""
    if recording.landmarks == "none":
        raise HandConversionError(f"{recording.name} has no landmarks yet: run the detector on it first "
                                  "(lerobot-ip-convert-hand --detector-model hand_landmarker.task)")
    if recording.landmarks == "world":
        landmarks_world, valid = recording.landmarks_world, np.ones(recording.num_frames, dtype=bool)
    else:
        landmarks_world = image_landmarks_in_world(recording, settings.window_px)
        with np.errstate(invalid="ignore"):
            valid = recording.hand_score >= settings.min_hand_score  # NaN (no hand): False
        if settings.hand is not None:
            valid &= recording.handedness == settings.hand
    try:
        trajectory = map_hand_to_gripper(landmarks_world, settings.mapping, valid, settings.window_frames,
                                         settings.aperture_window_frames, settings.dwell_frames)
    except HandGapError as error:
        raise HandGapError(f"{recording.name}: {error}") from error
    return HandEpisode(recording, landmarks_world, trajectory)


def image_landmarks_in_world(recording: HandRecording, window_px: int = 2) -> np.ndarray:
    """``landmarks_world (T, 21, 3)``: the recording's image landmarks lifted with its hand camera's depth, intrinsics
    and pose of each frame (``hand.lift_image_landmarks``)."""
    camera = recording.hand_camera
    depth = recording.depth_metres()[:, camera]
    return np.concatenate([
        lift_image_landmarks(recording.landmarks_px[frame:frame + 1], depth[frame:frame + 1],
                             recording.intrinsics[frame, camera], recording.T_world_camera[frame, camera], window_px)
        for frame in range(recording.num_frames)
    ])


def landmarks_for_masking(landmarks_world: np.ndarray) -> np.ndarray | None:
    """``landmarks_world (T, 21, 3)`` with each missing (NaN) landmark interpolated linearly in time from the frames
    that have it (held before the first and after the last); ``None`` when some landmark is in no frame."""
    filled = np.array(landmarks_world, dtype=np.float64)
    frames = np.arange(len(filled))
    for landmark in range(filled.shape[1]):
        known = np.all(np.isfinite(filled[:, landmark]), axis=1)
        if not known.any():
            return None
        for axis in range(3):
            filled[:, landmark, axis] = np.interp(frames, frames[known], filled[known, landmark, axis])
    return filled


def cloud_pipeline(settings: HandConvertSettings, with_hand_mask: bool,
                   with_object_mask: bool = False) -> PolicyProcessorPipeline:
    """Step 3 of the module docstring as a processor pipeline: ``depth (1, C, H, W)`` m, ``intrinsics``,
    ``T_world_camera``, ``hand_landmarks (1, 21, 3)`` (and ``hand_mask (1, C, H, W)``, ``object_mask (1, C, H, W)``)
    → ``pointcloud (1, N, 3)``."""
    steps = [DepthToPointCloudStep()]
    if with_hand_mask:
        steps.append(ClearHandPixelsStep(dilate_px=settings.hand_mask_dilate_px))
    steps.append(CropWorkspaceStep(low=tuple(settings.workspace_low), high=tuple(settings.workspace_high)))
    if not with_object_mask:  # the mask is the segmentation; the plane would also take what lies flat on the table
        steps.append(RemoveTablePlaneStep())
    steps += [MaskHandPointsStep(radius_m=settings.hand_radius_m), ResamplePointCloudStep(settings.num_points)]
    return PolicyProcessorPipeline(steps=steps, name="instant_policy_hand_perception")


def episode_clouds(episode: HandEpisode, settings: HandConvertSettings) -> np.ndarray:
    """``points (T, num_points, 3)`` float32, world frame: the recording's segmented clouds without the hand."""
    recording = episode.recording
    landmarks = landmarks_for_masking(episode.landmarks_world)
    if landmarks is None:
        raise HandConversionError(f"{recording.name}: some hand landmark is missing in every frame, so the hand "
                                  "cannot be removed from the clouds")
    pipeline = cloud_pipeline(settings, recording.hand_mask is not None, recording.object_mask is not None)
    depth = recording.depth_metres()
    clouds = []
    for frame in range(recording.num_frames):
        observation = {
            DEPTH_KEY: depth[frame:frame + 1],
            INTRINSICS_KEY: recording.intrinsics[frame:frame + 1].astype(np.float64),
            EXTRINSICS_KEY: recording.T_world_camera[frame:frame + 1].astype(np.float64),
            HAND_LANDMARKS_KEY: landmarks[frame:frame + 1],
        }
        if recording.hand_mask is not None:
            observation[HAND_MASK_KEY] = recording.hand_mask[frame:frame + 1]
        if recording.object_mask is not None:
            observation[OBJECT_MASK_KEY] = recording.object_mask[frame:frame + 1]
        try:
            clouds.append(np.asarray(pipeline(observation)[POINTCLOUD_KEY][0], dtype=np.float32))
        except (ValueError, RuntimeError) as error:
            raise HandConversionError(f"{recording.name}, frame {frame}: {error}") from error
    return np.stack(clouds)


def convert_hand_recordings(settings: HandConvertSettings) -> dict:
    """Convert every recording under ``settings.recordings`` (``hand_recording.find_hand_recordings``) into one
    dataset at ``settings.out``; returns a summary (root, episodes, frames, bridged frames per episode)."""
    from ..data.lerobot_format import create_dataset, write_episode

    episodes = [map_recording(load_hand_recording(folder), settings)
                for folder in find_hand_recordings(settings.recordings)]
    rates = {episode.recording.fps for episode in episodes}
    if len(rates) != 1:
        raise HandConversionError(f"the recordings have different frame rates {sorted(rates)}; one dataset has one")
    if settings.out.exists():
        if not settings.overwrite:
            raise FileExistsError(f"{settings.out} already exists; pass --overwrite to replace it")
        shutil.rmtree(settings.out)
    settings.out.parent.mkdir(parents=True, exist_ok=True)
    bridged = []
    try:
        output = create_dataset(settings.repo_id, settings.out, fps=rates.pop(), num_points=settings.num_points)
        for episode in episodes:
            states = episode.trajectory.state_vectors().astype(np.float32)
            actions = np.concatenate([states[1:], states[-1:]])
            write_episode(output, episode_clouds(episode, settings), states, actions, episode.recording.task)
            bridged.append({"recording": episode.recording.name, "frames": episode.recording.num_frames,
                            "bridged_frames": np.flatnonzero(~episode.trajectory.valid).tolist()})
        output.finalize()
        (settings.out / "meta" / HAND_FRAMES_FILE).write_text(json.dumps({"episodes": bridged}, indent=2) + "\n")
    except BaseException:
        shutil.rmtree(settings.out, ignore_errors=True)  # never leave a half-converted dataset behind
        raise
    return {"root": str(settings.out), "episodes": len(episodes),
            "frames": sum(item["frames"] for item in bridged), "bridged_frames": [item["bridged_frames"]
                                                                                  for item in bridged]}
