"""The frozen encoder's output for every frame of a training dataset, computed once and stored beside it.

The geometry encoder never trains, so what it makes of a frame's cloud (scene-node positions ``(M, 3)`` in the
frame's own EE frame and features ``(M, D)``) is the same at every step of every run. Training without this cache
re-encodes the live cloud of every batch row at every step, and the waypoints of every context episode once per
run; with it, a training step only reads rows (what that saves on a CPU and a GPU: docs/benchmarks.md).

Layout, under the dataset root::

    instant_policy_encodings/<encoder fingerprint>/
        scene_positions.npy   (F, M, 3) float32, frame f's nodes in frame f's EE frame (row = dataset ``index``)
        scene_features.npy    (F, M, D) float32
        meta.json             the encoder fingerprint, the dataset fingerprint, each data file's SHA-256, F, M, D,
                              and the frames copied from the cache it extended (0: built from scratch); written last

A cache is used only when its ``meta.json`` names the same encoder weights and the same dataset files (paths and
sizes); otherwise it is rebuilt. It is written in a temporary directory next to its final place and renamed into
place, so an interrupted build leaves no directory that could be mistaken for a cache, and the previous cache stays
in place until the new one replaces it.

A dataset that grew by appended episodes (``pseudo_demos/merge.py``'s ``append_datasets``, as training in rounds does) keeps
its old data files byte for byte and adds new ones after them, and its new frames' ``index`` values follow the old
ones. The cache of the old dataset is then **extended**, not rebuilt: ``meta.json`` also records the SHA-256 of every
data file, and when the cache's files are the first data files of the grown dataset with the same sizes and digests,
its F_old rows are copied and only frames F_old … F_new − 1 are encoded. Any other change (an old file rewritten,
removed or reordered) rebuilds the whole cache.
"""

from __future__ import annotations

import hashlib
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
COPY_CHUNK = 4096  # rows of a cache copied at once when it is extended

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


def data_file_digests(dataset_root: Path, data_files: list[list]) -> dict[str, str]:
    """SHA-256 of each file of ``data_files`` (``[relative path, size]`` pairs of :func:`frame_files_fingerprint`)."""
    digests = {}
    for relative, _ in data_files:
        with open(dataset_root / relative, "rb") as handle:
            digests[relative] = hashlib.file_digest(handle, "sha256").hexdigest()
    return digests


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
    0…F−1 (LeRobot writes it so). When the cache in place was built for the first F_old frames of this dataset (its
    data files are the dataset's first ones, unchanged: module docstring), those rows are copied and only frames
    F_old…F−1 are encoded; otherwise every frame is.
    """
    from ..contract import POINTCLOUD_KEY, STATE_KEY

    root = Path(dataset.root)
    path = cache_path(root, fingerprint)
    dataset_print = frame_files_fingerprint(root)
    frames = dataset_print["total_frames"]
    index = np.asarray(dataset.hf_dataset.with_format("numpy", columns=["index"])[:]["index"]).reshape(-1)
    if len(index) != frames or not np.array_equal(index, np.arange(frames)):
        raise ValueError(f"the dataset at {root} has frame indices that do not run 0…{frames - 1}; cannot cache them")
    digests = data_file_digests(root, dataset_print["data_files"])
    previous = _reusable_prefix(path, fingerprint, dataset_print, digests)
    first_new = 0 if previous is None else len(previous)
    _remove_abandoned_builds(path)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    started = time.perf_counter()
    columns = dataset.hf_dataset.with_format("numpy", columns=[POINTCLOUD_KEY, STATE_KEY])
    positions = features = None
    try:
        if previous is not None:
            positions, features = _open_arrays(tmp, frames, previous.scene_positions.shape[1:],
                                               previous.scene_features.shape[1:])
            for start in range(0, first_new, COPY_CHUNK):
                stop = min(start + COPY_CHUNK, first_new)
                positions[start:stop] = previous.scene_positions[start:stop]
                features[start:stop] = previous.scene_features[start:stop]
        for start in range(first_new, frames, batch_size):
            chunk = columns[start : start + batch_size]
            points = torch.from_numpy(np.ascontiguousarray(chunk[POINTCLOUD_KEY], dtype=np.float32)).to(device)
            state = torch.from_numpy(np.ascontiguousarray(chunk[STATE_KEY], dtype=np.float32)).to(device)
            with torch.no_grad():
                chunk_positions, chunk_features = encode(points, state)
            if positions is None:
                positions, features = _open_arrays(tmp, frames, chunk_positions.shape[1:], chunk_features.shape[1:])
            positions[start : start + len(points)] = chunk_positions.float().cpu().numpy()
            features[start : start + len(points)] = chunk_features.float().cpu().numpy()
            done, todo = start + len(points) - first_new, frames - first_new
            if done * 10 // todo > (start - first_new) * 10 // todo:
                logger.info(
                    "instant_policy: encoded %d / %d frames (%.0f s)", done, todo, time.perf_counter() - started
                )
        positions.flush()
        features.flush()
        meta = {
            "version": FORMAT_VERSION,
            "encoder": fingerprint,
            "dataset": dataset_print,
            "data_file_sha256": digests,
            "extended_from": first_new,
            "num_nodes": int(positions.shape[1]),
            "feature_dim": int(features.shape[2]),
        }
        del positions, features, previous
        (tmp / META_FILE).write_text(json.dumps(meta, indent=1))
        _replace_dir(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    if first_new:
        logger.info(
            "instant_policy: extended the frame encodings at %s from %d to %d frames (encoded the %d new frames of %s "
            "in %.0f s)", path, first_new, frames, frames - first_new, root, time.perf_counter() - started
        )
    else:
        logger.info(
            "instant_policy: encoded %d frames of %s in %.0f s into %s", frames, root, time.perf_counter() - started,
            path
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


def _reusable_prefix(
    path: Path, fingerprint: str, dataset_print: dict, digests: dict[str, str]
) -> FrameEncodings | None:
    """The cache at ``path`` when it holds this encoder's output for the first frames of the dataset described by
    ``dataset_print`` and ``digests``: its data files are the dataset's first data files, with the same sizes and
    SHA-256 (so its F_old frames are the dataset's frames 0…F_old−1, byte for byte). None otherwise."""
    try:
        meta = json.loads((path / META_FILE).read_text())
        if meta.get("version") != FORMAT_VERSION or meta.get("encoder") != fingerprint:
            return None
        old_files, old_digests = meta["dataset"]["data_files"], meta.get("data_file_sha256")
        old_frames = int(meta["dataset"]["total_frames"])
        if old_digests is None or dataset_print["data_files"][: len(old_files)] != old_files:
            return None
        if any(digests.get(name) != old_digests.get(name) for name, _ in old_files):
            logger.info("instant_policy: a data file of the frame encodings at %s changed: encoding every frame", path)
            return None
        if old_frames > dataset_print["total_frames"]:
            return None
        previous = FrameEncodings.open(path)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return previous if len(previous) == old_frames else None


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
