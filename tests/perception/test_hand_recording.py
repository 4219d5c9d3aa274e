"""Hand recordings on disk (``perception.hand_recording``), their conversion into demonstrations
(``perception.hand_convert``, ``lerobot-ip-convert-hand``) and the MediaPipe detector step
(``perception.hand_detector``).

The scene is synthetic: one camera looking down at a table with a 4 cm cube, and a hand (``landmarks_from_gripper``)
approaching, pinching and lifting it, its fingers and palm drawn as surfaces around its skeleton into the depth image.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from lerobot_instant_policy.cli.convert_hand import main
from lerobot_instant_policy.contract import vectors_from_poses
from lerobot_instant_policy.data.demonstrations import load_demonstrations
from lerobot_instant_policy.geometry.se3 import invert, transform_points
from lerobot_instant_policy.perception.hand import HandGapError, landmarks_from_gripper
from lerobot_instant_policy.perception.hand_convert import (
    HAND_FRAMES_FILE,
    HandConversionError,
    HandConvertSettings,
    convert_hand_recordings,
)
from lerobot_instant_policy.perception.hand_mask import HAND_BONES, PALM_TRIANGLES
from lerobot_instant_policy.perception.hand_recording import (
    FRAMES_FILE,
    METADATA_FILE,
    HandRecording,
    HandRecordingError,
    load_hand_recording,
    save_hand_recording,
)
from lerobot_instant_policy.sim.demonstrator import top_down_pose

WIDTH, HEIGHT, FOCAL = 96, 72, 90.0
CUBE_CENTRE, CUBE_HALF = np.array([0.5, 0.0, 0.02]), 0.02
INTRINSICS = np.array([[FOCAL, 0.0, WIDTH / 2 - 0.5], [0.0, FOCAL, HEIGHT / 2 - 0.5], [0.0, 0.0, 1.0]])


def _look_at(eye, target) -> np.ndarray:
    """``T_world_camera (4, 4)`` (OpenCV: x right, y down, z forward) of a camera at ``eye`` looking at ``target``."""
    z = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    x = np.cross(z, (0.0, 0.0, 1.0))
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = np.stack([x, np.cross(z, x), z], axis=1), eye
    return pose


T_WORLD_CAMERA = _look_at((0.85, 0.0, 0.4), (0.5, 0.0, 0.05))  # in front of the cube, looking down at it
FINGER_RADIUS = 0.008
# the hand's gripper poses (above, at, lifting the cube) and thumb-index apertures: open, then pinching the cube
HEIGHTS = (0.12, 0.07, 0.03, 0.015, 0.015, 0.015, 0.05, 0.09)
APERTURES = (0.09, 0.09, 0.09, 0.09, 0.03, 0.03, 0.03, 0.03)


def _surface_points(rng: np.random.Generator, landmarks: np.ndarray | None, cube_lift: float) -> np.ndarray:
    """World points of the table, the cube (raised by ``cube_lift``) and the hand's finger and palm surfaces."""
    table = np.c_[rng.uniform((0.2, -0.3), (0.85, 0.3), (60_000, 2)), np.zeros(60_000)]
    faces = rng.uniform(-CUBE_HALF, CUBE_HALF, (6000, 3))
    axis = rng.integers(0, 3, 6000)
    faces[np.arange(6000), axis] = np.sign(rng.uniform(-1, 1, 6000)) * CUBE_HALF
    points = [table, faces + CUBE_CENTRE + (0.0, 0.0, cube_lift)]
    if landmarks is not None:
        for first, second in HAND_BONES:
            along = rng.uniform(0, 1, (400, 1))
            direction = rng.normal(size=(400, 3))
            direction /= np.linalg.norm(direction, axis=1, keepdims=True)
            points.append(landmarks[first] + along * (landmarks[second] - landmarks[first]) + FINGER_RADIUS * direction)
        for corners in PALM_TRIANGLES:
            weights = rng.dirichlet(np.ones(3), 800)
            points.append(weights @ landmarks[list(corners)])
    return np.concatenate(points)


def _depth_image(points_world: np.ndarray) -> np.ndarray:
    """``(H, W)`` metres: the nearest of ``points_world`` splatted into the camera (a z-buffer)."""
    camera = transform_points(invert(T_WORLD_CAMERA), points_world)
    u = np.round(camera[:, 0] / camera[:, 2] * FOCAL + INTRINSICS[0, 2]).astype(int)
    v = np.round(camera[:, 1] / camera[:, 2] * FOCAL + INTRINSICS[1, 2]).astype(int)
    inside = (u >= 0) & (u < WIDTH) & (v >= 0) & (v < HEIGHT) & (camera[:, 2] > 0)
    depth = np.full(HEIGHT * WIDTH, np.inf)
    np.minimum.at(depth, v[inside] * WIDTH + u[inside], camera[inside, 2])
    return np.where(np.isfinite(depth), depth, 0.0).reshape(HEIGHT, WIDTH)


def _scene(noise_m: float = 0.0, seed: int = 0) -> tuple[HandRecording, np.ndarray, np.ndarray, np.ndarray]:
    """A world-landmark recording of the synthetic scene; the hand's true ``T_world_ee (T, 4, 4)``,
    ``landmarks (T, 21, 3)`` and the cube's lift per frame ``(T,)``."""
    rng = np.random.default_rng(seed)
    T_world_ee = np.stack([top_down_pose(CUBE_CENTRE + (0.0, 0.0, height - CUBE_CENTRE[2])) for height in HEIGHTS])
    landmarks = landmarks_from_gripper(T_world_ee, np.array(APERTURES))
    lift = np.array([max(0.0, height - 0.015) if aperture < 0.05 else 0.0
                     for height, aperture in zip(HEIGHTS, APERTURES, strict=True)])
    depth = np.stack([_depth_image(_surface_points(rng, hand, dz))[None] for hand, dz in zip(landmarks, lift,
                                                                                             strict=True)])
    frames = len(HEIGHTS)
    recording = HandRecording(
        task="pick up the cube", fps=10, rgb=np.zeros((frames, 1, HEIGHT, WIDTH, 3), np.uint8),
        depth=depth.astype(np.float32), intrinsics=np.broadcast_to(INTRINSICS, (frames, 1, 3, 3)),
        T_world_camera=np.broadcast_to(T_WORLD_CAMERA, (frames, 1, 4, 4)), landmarks="world",
        landmarks_world=landmarks + rng.normal(0.0, noise_m, landmarks.shape),
    )
    return recording, T_world_ee, landmarks, lift


def _image_landmarks(landmarks_world: np.ndarray) -> np.ndarray:
    """``(T, 21, 2)`` pixels of world landmarks in the scene's camera."""
    camera = transform_points(invert(T_WORLD_CAMERA), landmarks_world.reshape(-1, 3))
    pixels = camera[:, :2] / camera[:, 2:] * FOCAL + INTRINSICS[:2, 2]
    return pixels.reshape(*landmarks_world.shape[:2], 2)


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_round_trip_of_both_landmark_kinds(scene, tmp_path):
    recording, _, landmarks, _ = scene
    folder = save_hand_recording(recording, tmp_path / "world")
    loaded = load_hand_recording(folder)
    assert loaded.landmarks == "world" and loaded.task == recording.task and loaded.num_frames == len(HEIGHTS)
    np.testing.assert_array_equal(loaded.depth, recording.depth)
    np.testing.assert_array_equal(loaded.landmarks_world, recording.landmarks_world)
    frames = len(HEIGHTS)
    pixels = _image_landmarks(landmarks)
    pixels[2] = np.nan
    image = recording.with_image_landmarks(pixels, np.array(["Right"] * 2 + [""] + ["Right"] * (frames - 3)),
                                           np.r_[0.9, 0.9, np.nan, np.full(frames - 3, 0.9)])
    millimetres = HandRecording(**{**vars(image), "depth": np.round(image.depth * 1000).astype(np.uint16),
                                   "depth_unit": "mm", "hand_mask": image.depth > 0.4,
                                   "object_mask": image.depth > 0.45})
    loaded = load_hand_recording(save_hand_recording(millimetres, tmp_path / "image"))
    assert loaded.landmarks == "image" and loaded.landmarks_world is None and loaded.hand_mask.dtype == bool
    np.testing.assert_array_equal(loaded.object_mask, recording.depth > 0.45)
    np.testing.assert_array_equal(loaded.landmarks_px, pixels)
    assert loaded.handedness.tolist()[1:3] == ["Right", ""] and np.isnan(loaded.hand_score[2])
    assert np.abs(loaded.depth_metres() - recording.depth).max() <= 0.0005
    with pytest.raises(FileExistsError):
        save_hand_recording(millimetres, tmp_path / "image")


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(landmarks_world=np.zeros((8, 20, 3))), "landmarks_world must have shape"),
        (dict(landmarks_world=np.full((8, 21, 3), np.inf)), "infinite in frames"),
        (dict(rgb=np.zeros((8, 1, 72, 96, 3), np.float32)), "rgb must be uint8"),
        (dict(depth=np.zeros((1, 1, 72, 96), np.float32)), "at least 2 frames"),
        (dict(depth=np.zeros((8, 2, 72, 96), np.float32)), r"rgb must have shape \(T, C, H, W, 3\)"),
        (dict(depth=np.full((8, 1, 72, 96), 450.0, np.float32)), "not metres"),
        (dict(intrinsics=np.broadcast_to(np.diag([90.0, 90.0, 1.0]) + [[0, 0, 100], [0, 0, 0], [0, 0, 0]],
                                         (8, 1, 3, 3))), "frame 0, camera 0: principal point"),
        (dict(landmarks="image"), "needs exactly"),
        (dict(landmarks="glove"), "landmarks must be one of"),
        (dict(hand_camera=1), "hand_camera"),
        (dict(object_mask=np.ones((8, 1, 72, 95), bool)), "object_mask must have shape"),
        (dict(task=""), "task"),
    ],
)
def test_bad_recordings_are_refused_with_the_field_named(scene, change, message):
    recording, *_ = scene
    fields = {**vars(recording), **change}
    with pytest.raises(HandRecordingError, match=message):
        HandRecording(**fields)


def test_bad_image_landmarks_are_refused(scene):
    recording, _, landmarks, _ = scene
    pixels, frames = _image_landmarks(landmarks), len(HEIGHTS)
    with pytest.raises(HandRecordingError, match="handedness must be one of"):
        recording.with_image_landmarks(pixels, np.array(["right"] * frames), np.full(frames, 0.9))
    with pytest.raises(HandRecordingError, match=r"hand_score must lie in \[0, 1\]"):
        recording.with_image_landmarks(pixels, np.array(["Left"] * frames), np.full(frames, 1.5))


def test_bad_files_are_refused(scene, tmp_path):
    recording, *_ = scene
    with pytest.raises(HandRecordingError, match="no recording.json"):
        load_hand_recording(tmp_path)
    folder = save_hand_recording(recording, tmp_path / "r")
    metadata = json.loads((folder / METADATA_FILE).read_text())
    (folder / METADATA_FILE).write_text(json.dumps({**metadata, "camera": 0}))
    with pytest.raises(HandRecordingError, match=r"unknown keys \['camera'\]"):
        load_hand_recording(folder)
    (folder / METADATA_FILE).write_text(json.dumps({**metadata, "version": 2}))
    with pytest.raises(HandRecordingError, match="version 2"):
        load_hand_recording(folder)
    (folder / METADATA_FILE).write_text("{")
    with pytest.raises(HandRecordingError, match="not valid JSON"):
        load_hand_recording(folder)
    (folder / METADATA_FILE).write_text(json.dumps(metadata))
    np.savez(folder / FRAMES_FILE, depth=np.zeros(3), extra=np.zeros(3))
    with pytest.raises(HandRecordingError, match=r"unknown arrays \['extra'\], missing arrays"):
        load_hand_recording(folder)
    np.savez(folder / FRAMES_FILE, rgb=np.array([{"a": 1}], dtype=object))
    with pytest.raises(HandRecordingError, match="without pickles"):
        load_hand_recording(folder)


def _cloud_outside_cube(points: np.ndarray, lift: float, margin: float = 0.004) -> np.ndarray:
    """``(P,)`` True for points farther than ``margin`` outside the cube raised by ``lift``."""
    local = np.abs(points - CUBE_CENTRE - (0.0, 0.0, lift))
    return np.any(local > CUBE_HALF + margin, axis=1)


def test_conversion_gives_the_gripper_and_clouds_without_the_hand(scene, tmp_path):
    recording, T_world_ee, _, lift = scene
    save_hand_recording(recording, tmp_path / "recordings" / "episode_000")
    save_hand_recording(recording, tmp_path / "recordings" / "episode_001")
    out = tmp_path / "converted"
    summary = convert_hand_recordings(HandConvertSettings(tmp_path / "recordings", out, "local/hand", num_points=256))
    assert summary["episodes"] == 2 and summary["frames"] == 2 * len(HEIGHTS) and summary["bridged_frames"] == [[], []]
    demonstrations = load_demonstrations("local/hand", out, "pick up the cube", 2)
    gripper_open = np.array(APERTURES) > 0.05
    expected = vectors_from_poses(T_world_ee, gripper_open)
    for demonstration in demonstrations:
        assert demonstration.points_world.shape == (len(HEIGHTS), 256, 3)
        assert demonstration.state[:, :3] == pytest.approx(expected[:, :3], abs=1e-5)
        assert np.abs(np.abs(np.sum(demonstration.state[:, 3:7] * expected[:, 3:7], axis=1)) - 1).max() < 1e-5
        assert demonstration.state[:, 7].tolist() == gripper_open.astype(float).tolist()
        assert demonstration.action[:-1] == pytest.approx(demonstration.state[1:], abs=1e-6)
        for frame, points in enumerate(demonstration.points_world):
            assert not _cloud_outside_cube(points, lift[frame]).any(), f"a hand or table point in frame {frame}"
    assert json.loads((out / "meta" / HAND_FRAMES_FILE).read_text())["episodes"][0]["bridged_frames"] == []


def test_without_the_hand_mask_the_cloud_would_hold_the_hand(scene, tmp_path):
    """The control of the test above: at the pinch the unmasked cloud has points outside the cube (the hand)."""
    from lerobot_instant_policy.perception.hand_convert import cloud_pipeline
    from lerobot_instant_policy.perception.steps import DEPTH_KEY, EXTRINSICS_KEY, INTRINSICS_KEY

    recording, _, _, lift = scene
    settings = HandConvertSettings(tmp_path, tmp_path / "out", "local/x", num_points=256)
    pipeline = cloud_pipeline(settings, with_hand_mask=False)
    frame = 5
    far_away_hand = np.full((1, 21, 3), 10.0) + np.arange(21)[None, :, None] * 0.01
    observation = {DEPTH_KEY: recording.depth[frame:frame + 1], INTRINSICS_KEY: recording.intrinsics[frame:frame + 1],
                   EXTRINSICS_KEY: recording.T_world_camera[frame:frame + 1],
                   "observation.hand_landmarks": far_away_hand}
    points = np.asarray(pipeline(observation)["observation.pointcloud"][0])
    assert _cloud_outside_cube(points, lift[frame]).mean() > 0.2


MARKER_LOW, MARKER_HIGH = np.array([0.57, 0.06, 0.0]), np.array([0.63, 0.12, 0.001])  # a flat target on the table


def _with_marker(recording: HandRecording, lift: np.ndarray) -> HandRecording:
    """``recording`` with a 1 mm marker drawn on the table and ``object_mask``: the pixels that see the cube or the
    marker (the hand's pixels, and the table's, are not in it)."""
    rng = np.random.default_rng(1)
    marker = rng.uniform(MARKER_LOW, MARKER_HIGH, (4000, 3))
    marker[:, 2] = MARKER_HIGH[2]
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    rays = np.stack([(u - INTRINSICS[0, 2]) / FOCAL, (v - INTRINSICS[1, 2]) / FOCAL, np.ones_like(u, float)], axis=-1)
    drawn = _depth_image(marker)
    depths, masks = [], []
    for frame in range(recording.num_frames):
        depth = recording.depth[frame, 0].astype(np.float64)
        depth = np.where((drawn > 0) & ((depth == 0) | (drawn < depth)), drawn, depth)
        world = transform_points(T_WORLD_CAMERA, (rays * depth[..., None]).reshape(-1, 3)).reshape(HEIGHT, WIDTH, 3)
        # a pixel spans about 5 mm here, and its back-projected point lies up to that far off the surface it saw
        on_cube = np.all(np.abs(world - CUBE_CENTRE - (0.0, 0.0, lift[frame])) <= CUBE_HALF + 0.005, axis=-1) & \
            (world[..., 2] > lift[frame] + 0.005)
        on_marker = np.all((world[..., :2] >= MARKER_LOW[:2]) & (world[..., :2] <= MARKER_HIGH[:2]), axis=-1)
        depths.append(depth[None])
        masks.append(((on_cube | on_marker) & (depth > 0))[None])
    return HandRecording(**{**vars(recording), "depth": np.stack(depths).astype(np.float32),
                            "object_mask": np.stack(masks)})


def test_an_object_mask_keeps_a_flat_target_the_table_plane_takes(scene, tmp_path):
    """A segmenter's object mask is the conversion's segmentation: a marker 1 mm high stays in every frame's cloud
    beside the cube, with no table or hand point; converted without the mask, the table plane takes the marker."""
    recording, _, _, lift = scene
    marked = _with_marker(recording, lift)
    for with_mask in (True, False):
        folder = tmp_path / f"mask-{with_mask}"
        save_hand_recording(marked if with_mask else HandRecording(**{**vars(marked), "object_mask": None}),
                            folder / "recordings" / "episode_000")
        convert_hand_recordings(HandConvertSettings(folder / "recordings", folder / "out", "local/hand",
                                                    num_points=512))
        [demonstration] = load_demonstrations("local/hand", folder / "out", "pick up the cube", 1)
        for frame, points in enumerate(demonstration.points_world):
            on_marker = np.all((points >= MARKER_LOW - (0.005, 0.005, 0.0)) &
                               (points <= MARKER_HIGH + (0.005, 0.005, 0.005)), axis=1)
            if with_mask:
                assert on_marker.sum() > 50 and (~on_marker).sum() > 50, f"frame {frame}: the marker or cube missing"
                stray = _cloud_outside_cube(points, lift[frame], 0.006) & ~on_marker
                assert not stray.any(), f"frame {frame}: a table or hand point"
            else:
                assert not on_marker.any(), f"frame {frame}: the table plane left marker points"


def test_image_landmarks_convert_with_missing_frames_bridged_and_marked(scene, tmp_path):
    recording, T_world_ee, landmarks, _ = scene
    pixels = _image_landmarks(landmarks)
    frames = len(HEIGHTS)
    scores = np.full(frames, 0.95)
    scores[3] = 0.2  # below min_hand_score: missing
    handedness = np.array(["Right"] * frames)
    handedness[6] = "Left"  # not the hand asked for: missing
    image = recording.with_image_landmarks(pixels, handedness, scores)
    save_hand_recording(image, tmp_path / "image")
    out = tmp_path / "converted"
    assert main(["--recordings", str(tmp_path / "image"), "--out", str(out), "--repo-id", "local/image",
                 "--num-points", "128", "--hand", "Right"]) == 0
    bridged = json.loads((out / "meta" / HAND_FRAMES_FILE).read_text())["episodes"][0]["bridged_frames"]
    assert bridged == [3, 6]
    (demonstration,) = load_demonstrations("local/image", out, "pick up the cube", 1)
    # lifted to the hand's visible surface, not its bones: off by about a finger's thickness (more where the depth
    # window around a landmark falls on another finger), not by a lost or jumping hand
    assert np.abs(demonstration.state[:, :3] - T_world_ee[:, :3, 3]).max() < 0.04


def test_a_long_gap_is_refused_and_nothing_is_written(scene, tmp_path, capsys):
    recording, *_ = scene
    gappy = np.array(recording.landmarks_world)
    gappy[2:6] = np.nan
    save_hand_recording(HandRecording(**{**vars(recording), "landmarks_world": gappy}), tmp_path / "rec" / "a")
    before = (tmp_path / "rec" / "a" / FRAMES_FILE).read_bytes()
    out = tmp_path / "converted"
    with pytest.raises(HandGapError, match=r"rec/a: the hand is missing in frames 2..5"):
        convert_hand_recordings(HandConvertSettings(tmp_path / "rec", out, "local/x"))
    assert main(["--recordings", str(tmp_path / "rec"), "--out", str(out), "--repo-id", "local/x"]) == 2
    assert "frames 2..5" in capsys.readouterr().err
    assert not out.exists() and (tmp_path / "rec" / "a" / FRAMES_FILE).read_bytes() == before
    save_hand_recording(HandRecording(**{**vars(recording), "landmarks": "none", "landmarks_world": None}),
                        tmp_path / "bare")
    with pytest.raises(HandConversionError, match="no landmarks yet"):
        convert_hand_recordings(HandConvertSettings(tmp_path / "bare", out, "local/x"))
    assert not out.exists()
    out.mkdir()
    save_hand_recording(recording, tmp_path / "good")
    with pytest.raises(FileExistsError):
        convert_hand_recordings(HandConvertSettings(tmp_path / "good", out, "local/x"))


def _hand_landmarker_model() -> Path | None:
    path = os.environ.get("HAND_LANDMARKER_TASK")
    return Path(path) if path and Path(path).is_file() else None


def test_detector_step_writes_image_landmarks(scene, tmp_path):
    """MediaPipe's hand landmarker on a recording: needs the ``hand`` extra and ``HAND_LANDMARKER_TASK`` (the path
    of ``hand_landmarker.task``). On frames without a hand every frame comes back missing, in the recording's
    format; a missing model file is a clear error."""
    pytest.importorskip("mediapipe")
    model = _hand_landmarker_model()
    if model is None:
        pytest.skip("HAND_LANDMARKER_TASK does not name a hand_landmarker.task model file")
    from lerobot_instant_policy.perception.hand_detector import HandDetectorError, detect_recording_landmarks

    recording, *_ = scene
    bare = HandRecording(**{**vars(recording), "landmarks": "none", "landmarks_world": None,
                            "rgb": np.full(recording.rgb.shape, 200, np.uint8)})
    folder = save_hand_recording(bare, tmp_path / "bare")
    with pytest.raises(HandDetectorError, match="no hand landmarker model"):
        detect_recording_landmarks(folder, tmp_path / "missing.task")
    detected = detect_recording_landmarks(folder, model)
    loaded = load_hand_recording(folder)
    assert loaded.landmarks == detected.landmarks == "image" and loaded.landmarks_px.shape == (len(HEIGHTS), 21, 2)
    assert np.isnan(loaded.landmarks_px).all() and set(loaded.handedness.tolist()) == {""}
    with pytest.raises(HandDetectorError, match="already has image landmarks"):
        detect_recording_landmarks(folder, model)
