"""A human demonstration as recorded: per-frame RGB-D of calibrated cameras and the hand's 21 landmarks, on disk.

A recording is one folder (one demonstration, one episode of the converted dataset)::

    RECORDING/recording.json   {"format": "lerobot-ip-hand-recording", "version": 1, "task": "pick up the cube",
                                "fps": 10, "depth_unit": "mm", "landmarks": "image", "hand_camera": 0}
    RECORDING/frames.npz       the arrays below (``numpy.savez_compressed``, no pickled objects)

Arrays, for ``T`` frames of ``C`` cameras of ``H`` x ``W`` pixels:

    ``rgb (T, C, H, W, 3)`` uint8;
    ``depth (T, C, H, W)``: float metres (``depth_unit`` "m") or uint16 millimetres ("mm"); 0 or NaN: no return;
    ``intrinsics (T, C, 3, 3)`` and ``T_world_camera (T, C, 4, 4)`` float (``perception.calibration``: OpenCV
    pinhole, camera optical frame → world frame, metres), per frame so that a camera may move;
    with ``landmarks`` "image" (a detector's output, ``perception.hand_detector``): ``landmarks_px (T, 21, 2)``
    pixels ``(u, v)`` in camera ``hand_camera`` (MediaPipe's layout, ``perception.hand``), NaN where no hand was
    found, ``handedness (T,)`` str "Left", "Right" or "" (none found) and ``hand_score (T,)`` in [0, 1], NaN where none;
    with ``landmarks`` "world": ``landmarks_world (T, 21, 3)`` metres, world frame (a glove, a motion-capture system,
    the simulator), NaN where missing;
    with ``landmarks`` "none": no landmarks yet (the detector's input, ``lerobot-ip-convert-hand --detector-model``);
    optionally ``hand_mask (T, C, H, W)`` bool: the hand's pixels (a segmenting detector, the simulator);
    optionally ``object_mask (T, C, H, W)`` bool: the task objects' pixels (a segmenter run on the RGB such as SAM 2,
    the simulator's segmentation), which then replaces the table-plane segmentation of the conversion.

:func:`load_hand_recording` checks all of it and raises :class:`HandRecordingError` naming the recording, the field
and the frame; :func:`save_hand_recording` checks before it writes and writes a folder whole or not at all.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from .calibration import DEPTH_UNITS, CalibrationError, check_extrinsics, check_intrinsics
from .depth import DepthRange, DepthUnitError, check_depth_metres
from .hand import NUM_LANDMARKS

RECORDING_FORMAT = "lerobot-ip-hand-recording"
RECORDING_VERSION = 1
METADATA_FILE = "recording.json"
FRAMES_FILE = "frames.npz"
LANDMARK_KINDS = ("none", "image", "world")
HANDEDNESS = ("Left", "Right", "")
_ARRAYS = {"none": (), "image": ("landmarks_px", "handedness", "hand_score"), "world": ("landmarks_world",)}
_METADATA_KEYS = ("format", "version", "task", "fps", "depth_unit", "landmarks", "hand_camera")
_MASKS = ("hand_mask", "object_mask")  # optional per-pixel masks, (T, C, H, W) bool


class HandRecordingError(ValueError):
    """A hand recording that is missing, malformed or inconsistent (the message names the recording and field)."""


@dataclass
class HandRecording:
    """One demonstration by a hand (module docstring for the arrays' shapes, units and frames).

    ``landmarks_px``, ``handedness`` and ``hand_score`` are set when ``landmarks == "image"``, ``landmarks_world``
    when ``"world"``, none of them when ``"none"``; ``hand_mask`` and ``object_mask`` are optional. ``name`` says
    where it came from in error messages.
    """

    task: str
    fps: int
    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: np.ndarray
    T_world_camera: np.ndarray
    landmarks: str
    depth_unit: str = "m"
    hand_camera: int = 0
    landmarks_px: np.ndarray | None = None
    handedness: np.ndarray | None = None
    hand_score: np.ndarray | None = None
    landmarks_world: np.ndarray | None = None
    hand_mask: np.ndarray | None = None
    object_mask: np.ndarray | None = None
    name: str = field(default="recording", compare=False)

    def __post_init__(self):
        self.validate()

    @property
    def num_frames(self) -> int:
        return len(self.depth)

    @property
    def num_cameras(self) -> int:
        return self.depth.shape[1]

    def depth_metres(self) -> np.ndarray:
        """``depth (T, C, H, W)`` float32 metres (NaN returns as 0)."""
        depth = np.nan_to_num(self.depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        return depth * np.float32(DEPTH_UNITS[self.depth_unit])

    def with_image_landmarks(self, landmarks_px, handedness, hand_score) -> HandRecording:
        """This recording with a detector's ``landmarks_px (T, 21, 2)``, ``handedness (T,)``, ``hand_score (T,)`` in
        place of its landmarks (checked)."""
        return replace(self, landmarks="image", landmarks_px=landmarks_px, handedness=handedness,
                       hand_score=hand_score, landmarks_world=None)

    def validate(self) -> None:
        """Raise :class:`HandRecordingError` unless every field is as the module docstring says."""
        where = self.name
        if not isinstance(self.task, str) or not self.task.strip():
            raise HandRecordingError(f"{where}: task must be a non-empty string (the LeRobot task label)")
        if isinstance(self.fps, bool) or not isinstance(self.fps, int | np.integer) or self.fps <= 0:
            raise HandRecordingError(f"{where}: fps must be a positive integer, got {self.fps!r}")
        if self.landmarks not in LANDMARK_KINDS:
            raise HandRecordingError(f"{where}: landmarks must be one of {list(LANDMARK_KINDS)}, got "
                                     f"{self.landmarks!r}")
        if self.depth_unit not in DEPTH_UNITS:
            raise HandRecordingError(f"{where}: depth_unit must be one of {sorted(DEPTH_UNITS)}, got "
                                     f"{self.depth_unit!r}")
        self.depth = _array(self.depth, where, "depth", 4, "(T, C, H, W)")
        frames, cameras, height, width = self.depth.shape
        if frames < 2:
            raise HandRecordingError(f"{where}: a demonstration needs at least 2 frames, got {frames}")
        if self.depth_unit == "mm" and self.depth.dtype != np.uint16:
            raise HandRecordingError(f"{where}: depth in millimetres must be uint16, got {self.depth.dtype}")
        if self.depth_unit == "m" and not np.issubdtype(self.depth.dtype, np.floating):
            raise HandRecordingError(f"{where}: depth in metres must be float, got {self.depth.dtype}")
        self.rgb = _array(self.rgb, where, "rgb", 5, "(T, C, H, W, 3)", (frames, cameras, height, width, 3))
        if self.rgb.dtype != np.uint8:
            raise HandRecordingError(f"{where}: rgb must be uint8, got {self.rgb.dtype}")
        self.intrinsics = _array(self.intrinsics, where, "intrinsics", 4, "(T, C, 3, 3)", (frames, cameras, 3, 3))
        self.T_world_camera = _array(self.T_world_camera, where, "T_world_camera", 4, "(T, C, 4, 4)",
                                     (frames, cameras, 4, 4))
        if isinstance(self.hand_camera, bool) or not 0 <= int(self.hand_camera) < cameras:
            raise HandRecordingError(f"{where}: hand_camera must be a camera index in 0..{cameras - 1}, got "
                                     f"{self.hand_camera!r}")
        self.hand_camera = int(self.hand_camera)
        self._validate_landmarks(frames)
        for name in _MASKS:
            if getattr(self, name) is not None:
                setattr(self, name, _array(getattr(self, name), where, name, 4, "(T, C, H, W)", self.depth.shape) != 0)
        self._validate_cameras()

    def _validate_landmarks(self, frames: int) -> None:
        where = self.name
        present = {name for name in ("landmarks_px", "handedness", "hand_score", "landmarks_world")
                   if getattr(self, name) is not None}
        expected = set(_ARRAYS[self.landmarks])
        if present != expected:
            raise HandRecordingError(f"{where}: landmarks {self.landmarks!r} needs exactly {sorted(expected)}, got "
                                     f"{sorted(present)}")
        if self.landmarks == "none":
            return
        if self.landmarks == "world":
            self.landmarks_world = _finite_or_nan(_array(self.landmarks_world, where, "landmarks_world", 3,
                                                         "(T, 21, 3)", (frames, NUM_LANDMARKS, 3)), where,
                                                  "landmarks_world")
            return
        self.landmarks_px = _finite_or_nan(_array(self.landmarks_px, where, "landmarks_px", 3, "(T, 21, 2)",
                                                  (frames, NUM_LANDMARKS, 2)), where, "landmarks_px")
        self.handedness = _array(self.handedness, where, "handedness", 1, "(T,)", (frames,)).astype(str)
        unknown = sorted(set(self.handedness.tolist()) - set(HANDEDNESS))
        if unknown:
            raise HandRecordingError(f"{where}: handedness must be one of {list(HANDEDNESS)}, got {unknown}")
        self.hand_score = _finite_or_nan(_array(self.hand_score, where, "hand_score", 1, "(T,)", (frames,)), where,
                                         "hand_score")
        outside = np.flatnonzero(~np.isnan(self.hand_score) & ((self.hand_score < 0) | (self.hand_score > 1)))
        if len(outside):
            raise HandRecordingError(f"{where}: hand_score must lie in [0, 1] (NaN: no hand), not in frames "
                                     f"{outside.tolist()}")

    def _validate_cameras(self) -> None:
        frames, cameras, height, width = self.depth.shape
        depth = self.depth_metres()
        for frame in range(frames):
            for camera in range(cameras):
                where = f"{self.name}: frame {frame}, camera {camera}"
                try:
                    check_intrinsics(self.intrinsics[frame, camera], width, height, where)
                    check_extrinsics(self.T_world_camera[frame, camera], where)
                    check_depth_metres(depth[frame, camera], DepthRange(), where)
                except (CalibrationError, DepthUnitError) as error:
                    raise HandRecordingError(str(error)) from error


def _array(value, where: str, name: str, ndim: int, shape_text: str, shape: tuple | None = None) -> np.ndarray:
    """``value`` as a numpy array of ``ndim`` dimensions (and exactly ``shape`` when given), else an error."""
    array = np.asarray(value)
    if array.ndim != ndim or (shape is not None and array.shape != tuple(shape)):
        expected = shape_text if shape is None else f"{shape_text} = {tuple(shape)}"
        raise HandRecordingError(f"{where}: {name} must have shape {expected}, got {array.shape}")
    if array.dtype == object:
        raise HandRecordingError(f"{where}: {name} holds Python objects; store plain numbers or strings")
    return array


def _finite_or_nan(array: np.ndarray, where: str, name: str) -> np.ndarray:
    """``array`` as float64 where every entry is a finite number or NaN (missing), else an error naming the frames."""
    if not np.issubdtype(array.dtype, np.number):
        raise HandRecordingError(f"{where}: {name} must be numbers, got {array.dtype}")
    array = array.astype(np.float64)
    infinite = np.isinf(array).reshape(len(array), -1).any(axis=1)
    if infinite.any():
        raise HandRecordingError(f"{where}: {name} is infinite in frames {np.flatnonzero(infinite).tolist()} "
                                 "(mark a missing value NaN)")
    return array


def save_hand_recording(recording: HandRecording, folder: str | Path, overwrite: bool = False) -> Path:
    """Write ``recording`` as the folder ``folder`` (module docstring), whole or not at all; returns the folder."""
    folder = Path(folder)
    recording.validate()
    if folder.exists() and not overwrite:
        raise FileExistsError(f"{folder} already exists; pass overwrite=True to replace it")
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    try:
        metadata = {"format": RECORDING_FORMAT, "version": RECORDING_VERSION, "task": recording.task,
                    "fps": int(recording.fps), "depth_unit": recording.depth_unit, "landmarks": recording.landmarks,
                    "hand_camera": recording.hand_camera}
        (staging / METADATA_FILE).write_text(json.dumps(metadata, indent=2) + "\n")
        arrays = {"rgb": recording.rgb, "depth": recording.depth, "intrinsics": recording.intrinsics,
                  "T_world_camera": recording.T_world_camera}
        arrays.update({name: getattr(recording, name) for name in _ARRAYS[recording.landmarks]})
        arrays.update({name: getattr(recording, name) for name in _MASKS if getattr(recording, name) is not None})
        np.savez_compressed(staging / FRAMES_FILE, **arrays)
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return folder


def load_hand_recording(folder: str | Path) -> HandRecording:
    """The checked recording in ``folder`` (module docstring); :class:`HandRecordingError` says what is wrong."""
    folder = Path(folder)
    metadata_path, frames_path = folder / METADATA_FILE, folder / FRAMES_FILE
    for path in (metadata_path, frames_path):
        if not path.is_file():
            raise HandRecordingError(f"{folder}: no {path.name}; a hand recording holds {METADATA_FILE} and "
                                     f"{FRAMES_FILE}")
    try:
        metadata = json.loads(metadata_path.read_text())
    except json.JSONDecodeError as error:
        raise HandRecordingError(f"{metadata_path} is not valid JSON: {error}") from error
    if not isinstance(metadata, dict) or metadata.get("format") != RECORDING_FORMAT:
        raise HandRecordingError(f"{metadata_path}: not a hand recording (\"format\" must be {RECORDING_FORMAT!r})")
    if metadata.get("version") != RECORDING_VERSION:
        raise HandRecordingError(f"{metadata_path}: version {metadata.get('version')!r}; this package reads version "
                                 f"{RECORDING_VERSION}")
    unknown = sorted(set(metadata) - set(_METADATA_KEYS))
    missing = sorted({"task", "fps", "landmarks"} - set(metadata))
    if unknown or missing:
        raise HandRecordingError(f"{metadata_path}: unknown keys {unknown}, missing keys {missing}; expected "
                                 f"{list(_METADATA_KEYS)}")
    try:
        with np.load(frames_path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError) as error:
        raise HandRecordingError(f"{frames_path} is not a readable numpy archive without pickles: {error}") from error
    known = {item.name for item in fields(HandRecording)} - set(_METADATA_KEYS) - {"name"}
    unknown = sorted(set(arrays) - known)
    missing = sorted({"rgb", "depth", "intrinsics", "T_world_camera"} - set(arrays))
    if unknown or missing:
        raise HandRecordingError(f"{frames_path}: unknown arrays {unknown}, missing arrays {missing}")
    return HandRecording(task=metadata["task"], fps=metadata["fps"], landmarks=metadata["landmarks"],
                         depth_unit=metadata.get("depth_unit", "m"), hand_camera=metadata.get("hand_camera", 0),
                         name=str(folder), **arrays)


def find_hand_recordings(root: str | Path) -> list[Path]:
    """``root`` itself when it is a recording, else its sub-folders that are, sorted by name; an error for none."""
    root = Path(root)
    if (root / METADATA_FILE).is_file():
        return [root]
    folders = sorted(path for path in root.iterdir() if (path / METADATA_FILE).is_file()) if root.is_dir() else []
    if not folders:
        raise HandRecordingError(f"{root} holds no hand recording (a folder with {METADATA_FILE}, or folders of them)")
    return folders
