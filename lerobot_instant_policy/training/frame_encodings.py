"""The frozen encoder's output for every frame of a training dataset, computed once and stored beside it.

The geometry encoder never trains, so what it makes of a frame's cloud (scene-node positions ``(M, 3)`` in the
frame's own EE frame and features ``(M, D)``) is the same at every step of every run. Training without this cache
re-encodes the live cloud of every batch row at every step, and the waypoints of every context episode once per
run; with it, a training step only reads rows (what that saves on a CPU and a GPU: docs/benchmarks.md).

Layout, under the dataset root::

    instant_policy_encodings/<encoder fingerprint>/
        scene_positions.npy   (F, M, 3) float32, frame f's nodes in frame f's EE frame (row = dataset ``index``)
        scene_features.npy    (F, M, D) float32
        meta.json             the encoder fingerprint, the dataset fingerprint, F, M, D; written last

A cache is used only when its ``meta.json`` names the same encoder weights and the same dataset files (paths and
sizes); otherwise it is rebuilt. It is written in a temporary directory next to its final place and renamed into
place, so an interrupted build leaves no directory that could be mistaken for a cache, and the previous cache stays
in place until the new one replaces it.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

logger = logging.getLogger(__name__)

CACHE_DIR = "instant_policy_encodings"
META_FILE = "meta.json"
FORMAT_VERSION = 1

# (points_world (B, P, 3), state (B, 8)) on the encoder's device → positions (B, M, 3), features (B, M, D)
EncodeFrames = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


@dataclass(frozen=True)
class FrameEncodings:
    """The cache of one dataset for one encoder: ``scene_positions (F, M, 3)`` and ``scene_features (F, M, D)``
    (read-only memory maps of the files at ``path``, or arrays in memory with ``path`` None), indexed by the
    dataset's global frame ``index``."""

    path: Path | None
    scene_positions: np.ndarray
    scene_features: np.ndarray

    @classmethod
    def open(cls, path: Path) -> FrameEncodings:
        return cls(
            path,
            np.load(path / "scene_positions.npy", mmap_mode="r"),
            np.load(path / "scene_features.npy", mmap_mode="r"),
        )

    def __len__(self) -> int:
        return len(self.scene_positions)

    def lookup(self, indices, device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
        """Positions ``(..., M, 3)`` and features ``(..., M, D)`` of the frames ``indices (...)`` (dataset ``index``)."""
        flat = np.asarray(indices, dtype=np.int64).reshape(-1)
        if flat.size and (flat.min() < 0 or flat.max() >= len(self)):
            raise IndexError(f"frame indices {flat.min()}…{flat.max()} outside the {len(self)} frames of {self.path}")
        shape = np.shape(indices)
        positions = torch.from_numpy(self.scene_positions[flat]).reshape(*shape, *self.scene_positions.shape[1:])
        features = torch.from_numpy(self.scene_features[flat]).reshape(*shape, *self.scene_features.shape[1:])
        return positions.to(device), features.to(device)


def frame_files_fingerprint(dataset_root: Path) -> dict:
    """What identifies a dataset's frames: the relative path and size of every file under ``data/``, and
    ``meta/info.json``'s frame count. A regenerated or grown dataset changes it."""
    info = json.loads((dataset_root / "meta" / "info.json").read_text())
    files = sorted(
        (str(path.relative_to(dataset_root)), path.stat().st_size)
        for path in (dataset_root / "data").rglob("*")
        if path.is_file()
    )
    return {"total_frames": int(info["total_frames"]), "data_files": [list(item) for item in files]}


def cache_path(dataset_root: str | Path, fingerprint: str) -> Path:
    return Path(dataset_root) / CACHE_DIR / fingerprint[:16]


def load_frame_encodings(dataset_root: str | Path, fingerprint: str) -> FrameEncodings | None:
    """The valid cache of ``dataset_root`` for the encoder ``fingerprint``, or None (absent, stale or unreadable)."""
    path = cache_path(dataset_root, fingerprint)
    try:
        meta = json.loads((path / META_FILE).read_text())
    except (OSError, ValueError):
        return None
    expected = {"version": FORMAT_VERSION, "encoder": fingerprint, "dataset": frame_files_fingerprint(Path(dataset_root))}
    if any(meta.get(key) != value for key, value in expected.items()):
        logger.info("instant_policy: the frame encodings at %s are stale (dataset or encoder changed)", path)
        return None
    encodings = FrameEncodings.open(path)
    if len(encodings) != meta["dataset"]["total_frames"]:
        return None
    return encodings


def build_frame_encodings(
    dataset,
    fingerprint: str,
    encode: EncodeFrames,
    device: torch.device | str,
    batch_size: int = 256,
) -> FrameEncodings:
    """Encode the frames of ``dataset`` (a ``LeRobotDataset`` in the data contract) and store the cache.

    ``encode`` gets each chunk of ``batch_size`` frames' ``observation.pointcloud`` and ``observation.state`` as
    float32 tensors on ``device``. Frames are stored in the order of the dataset's ``index`` column, which must run
    0…F−1 (LeRobot writes it so).
    """
    from ..contract import POINTCLOUD_KEY, STATE_KEY

    root = Path(dataset.root)
    path = cache_path(root, fingerprint)
    dataset_print = frame_files_fingerprint(root)
    frames = dataset_print["total_frames"]
    index = np.asarray(dataset.hf_dataset.with_format("numpy", columns=["index"])[:]["index"]).reshape(-1)
    if len(index) != frames or not np.array_equal(index, np.arange(frames)):
        raise ValueError(f"the dataset at {root} has frame indices that do not run 0…{frames - 1}; cannot cache them")
    _remove_abandoned_builds(path)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    started = time.perf_counter()
    columns = dataset.hf_dataset.with_format("numpy", columns=[POINTCLOUD_KEY, STATE_KEY])
    positions = features = None
    try:
        for start in range(0, frames, batch_size):
            chunk = columns[start : start + batch_size]
            points = torch.from_numpy(np.ascontiguousarray(chunk[POINTCLOUD_KEY], dtype=np.float32)).to(device)
            state = torch.from_numpy(np.ascontiguousarray(chunk[STATE_KEY], dtype=np.float32)).to(device)
            with torch.no_grad():
                chunk_positions, chunk_features = encode(points, state)
            if positions is None:
                positions, features = _open_arrays(tmp, frames, chunk_positions.shape[1:], chunk_features.shape[1:])
            positions[start : start + len(points)] = chunk_positions.float().cpu().numpy()
            features[start : start + len(points)] = chunk_features.float().cpu().numpy()
            done = start + len(points)
            if done * 10 // frames > start * 10 // frames:
                logger.info(
                    "instant_policy: encoded %d / %d frames (%.0f s)", done, frames, time.perf_counter() - started
                )
        positions.flush()
        features.flush()
        meta = {
            "version": FORMAT_VERSION,
            "encoder": fingerprint,
            "dataset": dataset_print,
            "num_nodes": int(positions.shape[1]),
            "feature_dim": int(features.shape[2]),
        }
        del positions, features
        (tmp / META_FILE).write_text(json.dumps(meta, indent=1))
        _replace_dir(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    logger.info(
        "instant_policy: encoded %d frames of %s in %.0f s into %s", frames, root, time.perf_counter() - started, path
    )
    return FrameEncodings.open(path)


def _open_arrays(directory: Path, frames: int, position_shape: tuple, feature_shape: tuple):
    """New ``scene_positions (F, M, 3)`` and ``scene_features (F, M, D)`` float32 ``.npy`` memory maps in
    ``directory``."""
    positions = np.lib.format.open_memmap(
        directory / "scene_positions.npy", "w+", np.float32, (frames, *position_shape)
    )
    features = np.lib.format.open_memmap(directory / "scene_features.npy", "w+", np.float32, (frames, *feature_shape))
    return positions, features


def _remove_abandoned_builds(path: Path) -> None:
    """Delete the temporary directories of builds of ``path`` whose process no longer runs (killed mid-build)."""
    for tmp in path.parent.glob(f".{path.name}.tmp-*"):
        pid = tmp.name.rpartition("-")[2]
        if pid.isdigit() and int(pid) != os.getpid() and not Path(f"/proc/{pid}").exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _replace_dir(new: Path, final: Path) -> None:
    """Move the finished directory ``new`` to ``final``, replacing a stale one there. Processes that build the same
    cache at once (one per GPU under ``accelerate launch``) each write their own ``new``; when another one's lands in
    between, the rename fails and the last one in place stays."""
    if final.exists():
        stale = final.parent / f".{final.name}.stale-{os.getpid()}"
        try:
            final.rename(stale)
        except FileNotFoundError:  # another process replaced it first
            pass
        else:
            shutil.rmtree(stale)
    try:
        new.rename(final)
    except OSError:
        if not (final / META_FILE).is_file():
            raise
