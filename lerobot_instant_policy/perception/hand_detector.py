"""The hand detector step: MediaPipe's hand landmarker (Tasks API) on a recording's RGB frames → image landmarks.

MediaPipe is an optional extra (``pip install 'lerobot_policy_instant_policy[hand]'``) and its wheel ships no model:
download ``hand_landmarker.task`` (MediaPipe's hand landmark model bundle, ``HAND_LANDMARKER_URL``) and pass its path.
The landmarker runs in video mode (it tracks the hand from frame to frame) with one hand, on the frames of the
recording's ``hand_camera``. Per frame it gives ``landmarks_px (21, 2)``: MediaPipe's normalised image coordinates
times the image width and height (pixels ``(u, v)``, what ``hand.lift_image_landmarks`` reads), the ``handedness``
("Left" / "Right", as MediaPipe names the hand) and its score; a frame where no hand is found is NaN, "" and NaN.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .hand import NUM_LANDMARKS
from .hand_recording import HandRecording, load_hand_recording, save_hand_recording

HAND_LANDMARKER_URL = (
    "https://storage.googleapis.com/mediapipe-models/hand_landmarker/hand_landmarker/float16/latest/"
    "hand_landmarker.task"
)


class HandDetectorError(RuntimeError):
    """MediaPipe or its model file is missing, or the frames cannot be read by it."""


def detect_image_landmarks(
    rgb: np.ndarray, model_path: str | Path, fps: int, min_confidence: float = 0.5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MediaPipe's hand landmarker on ``rgb (T, H, W, 3)`` uint8 frames at ``fps`` → ``landmarks_px (T, 21, 2)``
    pixels, ``handedness (T,)`` str and ``hand_score (T,)`` (module docstring). ``min_confidence``: MediaPipe's
    detection, presence and tracking confidences."""
    vision, base_options, image_class, image_format = _mediapipe()
    model_path = Path(model_path)
    if not model_path.is_file():
        raise HandDetectorError(f"no hand landmarker model at {model_path}: download {HAND_LANDMARKER_URL}")
    rgb = np.asarray(rgb)
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or rgb.dtype != np.uint8:
        raise HandDetectorError(f"rgb must be (T, H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    frames, height, width = rgb.shape[:3]
    landmarks_px = np.full((frames, NUM_LANDMARKS, 2), np.nan)
    handedness = np.full(frames, "", dtype="<U5")
    hand_score = np.full(frames, np.nan)
    options = vision.HandLandmarkerOptions(
        base_options=base_options(model_asset_path=str(model_path)), running_mode=vision.RunningMode.VIDEO,
        num_hands=1, min_hand_detection_confidence=min_confidence, min_hand_presence_confidence=min_confidence,
        min_tracking_confidence=min_confidence,
    )
    with vision.HandLandmarker.create_from_options(options) as landmarker:
        for frame in range(frames):
            image = image_class(image_format=image_format.SRGB, data=np.ascontiguousarray(rgb[frame]))
            result = landmarker.detect_for_video(image, int(round(1000.0 * frame / fps)))
            if not result.hand_landmarks:
                continue
            landmarks_px[frame] = [(point.x * width, point.y * height) for point in result.hand_landmarks[0]]
            category = result.handedness[0][0]
            handedness[frame], hand_score[frame] = category.category_name, category.score
    return landmarks_px, handedness, hand_score


def detect_recording_landmarks(
    folder: str | Path, model_path: str | Path, overwrite: bool = False, min_confidence: float = 0.5
) -> HandRecording:
    """Run :func:`detect_image_landmarks` on the recording in ``folder`` (its ``hand_camera``'s frames) and write the
    image landmarks into it (the folder is replaced whole); a recording that already has landmarks is refused unless
    ``overwrite``. Returns the updated recording."""
    recording = load_hand_recording(folder)
    if recording.landmarks != "none" and not overwrite:
        raise HandDetectorError(f"{folder} already has {recording.landmarks} landmarks; pass overwrite to detect again")
    detected = detect_image_landmarks(recording.rgb[:, recording.hand_camera], model_path, recording.fps,
                                      min_confidence)
    updated = recording.with_image_landmarks(*detected)
    save_hand_recording(updated, folder, overwrite=True)
    return updated


def _mediapipe():
    """MediaPipe's vision tasks, ``BaseOptions``, ``Image`` and ``ImageFormat``, or a :class:`HandDetectorError`."""
    try:
        import mediapipe
        from mediapipe.tasks.python import BaseOptions, vision
    except ImportError as error:
        raise HandDetectorError(
            "the hand detector needs MediaPipe: pip install 'lerobot_policy_instant_policy[hand]' "
            f"(docs/deployment.md section 8); {error}"
        ) from error
    return vision, BaseOptions, mediapipe.Image, mediapipe.ImageFormat
