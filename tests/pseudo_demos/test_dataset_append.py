"""Growing a dataset in place (``merge.append_datasets``) and extending its frame-encoding cache (issue 12.6): the
old frames keep their data files byte for byte and their ``index`` values, the cache of the old dataset is extended
with the new frames only and equals a full rebuild, a changed old file forces a full rebuild, and interruptions of
either leave the previous state usable."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from synthetic_demos import NUM_FRAMES, object_pose, write_demo_dataset

from lerobot_instant_policy.pseudo_demos import merge
from lerobot_instant_policy.training.frame_encodings import (
    META_FILE,
    build_frame_encodings,
    cache_path,
    load_frame_encodings,
)

FINGERPRINT = "f" * 64
BATCH = 16
POSES = [object_pose(0.5, 0.0, 0.0), object_pose(0.45, 0.1, 20.0), object_pose(0.4, 0.15, 55.0),
         object_pose(0.55, -0.1, -40.0)]


class CountingEncoder:
    """A deterministic stand-in for the frozen encoder (each row's output depends on that row only, so batching does
    not change it): positions ``(B, 4, 3)`` the first 4 points minus the EE position, features ``(B, 4, 11)`` the
    points and the state. Counts the frames it encodes; ``fail_on_call`` raises KeyboardInterrupt on that call."""

    def __init__(self, fail_on_call: int | None = None):
        self.frames, self.calls, self.fail_on_call = 0, 0, fail_on_call

    def __call__(self, points: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self.calls += 1
        if self.calls == self.fail_on_call:
            raise KeyboardInterrupt
        self.frames += len(points)
        nodes = points[:, :4]
        features = torch.cat([nodes, state[:, None, :].expand(-1, 4, -1)], dim=-1)
        return nodes - state[:, None, :3], features


def _open(root: Path, repo_id: str = "local/train"):
    from lerobot.datasets import LeRobotDataset

    return LeRobotDataset(repo_id, root=root)


def _files(root: Path) -> dict[str, bytes]:
    return {str(path.relative_to(root)): path.read_bytes() for path in sorted(root.rglob("*")) if path.is_file()}


@pytest.fixture(scope="module")
def rounds(tmp_path_factory) -> list[Path]:
    """Three small datasets, as three rounds of pseudo-tasks: 4 episodes (48 frames, a multiple of BATCH, so that a
    full build and an extension encode the same batches), 2 episodes and 2 episodes, each with its own tasks."""
    base = tmp_path_factory.mktemp("rounds")
    episodes = [[("lift", POSES[0]), ("lift", POSES[1]), ("push", POSES[2]), ("push", POSES[3])],
                [("stack", POSES[1]), ("stack", POSES[3])],
                [("slide", POSES[0]), ("slide", POSES[2])]]
    roots = []
    for number, round_episodes in enumerate(episodes):
        root = base / f"round-{number}"
        write_demo_dataset(root, f"local/round-{number}", round_episodes, seed=10 * number)
        for name in ("pseudo_tasks.jsonl", "pseudo_demos.jsonl"):
            (root / "meta" / name).write_text("".join(f'{{"round": {number}}}\n' for _ in round_episodes))
        roots.append(root)
    return roots


def _grow(train: Path, rounds: list[Path], numbers: list[int]) -> None:
    merge.append_datasets(train, "local/train", [rounds[n] for n in numbers], [f"local/round-{n}" for n in numbers],
                          meta_files=("pseudo_tasks.jsonl", "pseudo_demos.jsonl"))


def test_append_keeps_old_files_and_equals_a_merge_of_all_rounds(rounds, tmp_path):
    train = tmp_path / "train"
    _grow(train, rounds, [0])
    first = _files(train / "data")
    _grow(train, rounds, [1])
    _grow(train, rounds, [2])
    assert sorted(path.name for path in train.iterdir()) == ["data", "meta"]

    grown = _open(train)
    assert grown.meta.total_episodes == 8 and grown.meta.total_frames == 8 * NUM_FRAMES == len(grown.hf_dataset)
    np.testing.assert_array_equal(np.asarray(grown.hf_dataset.with_format("numpy")["index"]), np.arange(8 * NUM_FRAMES))
    assert list(grown.meta.tasks.index) == ["lift", "push", "stack", "slide"]
    # the first round's data file is untouched (hard-linked through both appends); the rounds follow it in order
    assert {name: data for name, data in _files(train / "data").items() if name in first} == first
    assert len(_files(train / "data")) == 3
    lines = (train / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()
    assert [json.loads(line)["round"] for line in lines] == [0, 0, 0, 0, 1, 1, 2, 2]

    # the same dataset as one merge of the three rounds, column for column and in its metadata
    merge.merge_parallel(rounds, [f"local/round-{n}" for n in range(3)], "local/train", tmp_path / "merged")
    merged = _open(tmp_path / "merged")
    assert merged.meta.info.to_dict() == grown.meta.info.to_dict()
    assert merged.meta.tasks.equals(grown.meta.tasks)
    assert merged.meta.episodes.to_pandas().equals(grown.meta.episodes.to_pandas())
    for column in merged.hf_dataset.column_names:
        np.testing.assert_array_equal(np.asarray(grown.hf_dataset.with_format("numpy")[column]),
                                      np.asarray(merged.hf_dataset.with_format("numpy")[column]))


def test_an_interrupted_append_leaves_the_dataset_as_it_was_or_finishes(rounds, tmp_path):
    train = tmp_path / "train"
    _grow(train, rounds, [0])
    before = _files(train)

    # staged but never marked complete (killed while merging): dropped, the dataset unchanged
    staging = merge.prepare_append(train, "local/train", [rounds[1]], ["local/round-1"])
    (staging / merge.APPEND_COMPLETE).unlink()
    assert not merge.finish_append(train) and _files(train) == before

    # complete but killed halfway through the swap (data/ in place, meta/ not yet): finished on the next call
    staging = merge.prepare_append(train, "local/train", [rounds[1]], ["local/round-1"])
    with pytest.raises(FileExistsError, match="finish_append"):
        merge.prepare_append(train, "local/train", [rounds[2]], ["local/round-2"])
    shutil.rmtree(train / "data")
    (staging / "data").rename(train / "data")
    assert merge.finish_append(train)
    assert not staging.exists() and _open(train).meta.total_episodes == 6
    assert not merge.finish_append(train)
    with pytest.raises(ValueError, match="at least one"):
        merge.append_datasets(train, "local/train", [], [])


def test_a_grown_dataset_extends_its_cache_to_the_arrays_of_a_full_build(rounds, tmp_path):
    train = tmp_path / "train"
    _grow(train, rounds, [0])
    first = CountingEncoder()
    build_frame_encodings(_open(train), FINGERPRINT, first, "cpu", batch_size=BATCH)
    assert first.frames == 4 * NUM_FRAMES

    _grow(train, rounds, [1, 2])
    assert load_frame_encodings(train, FINGERPRINT) is None  # stale for the grown dataset
    extension = CountingEncoder()
    extended = build_frame_encodings(_open(train), FINGERPRINT, extension, "cpu", batch_size=BATCH)
    assert extension.frames == 4 * NUM_FRAMES  # the new frames only
    meta = json.loads((cache_path(train, FINGERPRINT) / META_FILE).read_text())
    assert meta["extended_from"] == 4 * NUM_FRAMES and meta["dataset"]["total_frames"] == 8 * NUM_FRAMES
    assert load_frame_encodings(train, FINGERPRINT) is not None

    copy = tmp_path / "copy"
    shutil.copytree(train, copy, ignore=shutil.ignore_patterns("instant_policy_encodings"))
    rebuild = CountingEncoder()
    full = build_frame_encodings(_open(copy), FINGERPRINT, rebuild, "cpu", batch_size=BATCH)
    assert rebuild.frames == 8 * NUM_FRAMES
    assert json.loads((cache_path(copy, FINGERPRINT) / META_FILE).read_text())["extended_from"] == 0
    np.testing.assert_array_equal(extended.scene_positions, full.scene_positions)
    np.testing.assert_array_equal(extended.scene_features, full.scene_features)


def test_a_changed_old_file_forces_a_full_rebuild(rounds, tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    from lerobot.datasets.io_utils import write_table_one_row_group_per_episode

    train = tmp_path / "train"
    _grow(train, rounds, [0])
    build_frame_encodings(_open(train), FINGERPRINT, CountingEncoder(), "cpu", batch_size=BATCH)
    path = cache_path(train, FINGERPRINT)
    _grow(train, rounds, [1])

    # a digest that no longer matches (the same path and size, other bytes) is not extended
    meta = json.loads((path / META_FILE).read_text())
    name = meta["dataset"]["data_files"][0][0]
    meta["data_file_sha256"][name] = "0" * 64
    (path / META_FILE).write_text(json.dumps(meta))
    encoder = CountingEncoder()
    build_frame_encodings(_open(train), FINGERPRINT, encoder, "cpu", batch_size=BATCH)
    assert encoder.frames == 6 * NUM_FRAMES

    # an old episode rewritten with another cloud: every frame is encoded again and the cache has the new cloud
    table = pq.read_table(train / name)
    clouds = table.column("observation.pointcloud").to_pylist()
    clouds[0][0] = [value + 0.25 for value in clouds[0][0]]
    column = table.schema.get_field_index("observation.pointcloud")
    field = table.schema.field(column)
    table = table.set_column(column, field, pa.array(clouds, type=field.type))
    write_table_one_row_group_per_episode(table, train / name)
    encoder = CountingEncoder()
    rebuilt = build_frame_encodings(_open(train), FINGERPRINT, encoder, "cpu", batch_size=BATCH)
    assert encoder.frames == 6 * NUM_FRAMES
    assert json.loads((path / META_FILE).read_text())["extended_from"] == 0
    first_state = _open(train)[0]["observation.state"]
    assert rebuilt.scene_positions[0, 0, 0] == pytest.approx(clouds[0][0][0] - float(first_state[0]))


def test_an_interrupted_extension_keeps_the_old_cache_and_the_next_build_extends_it(rounds, tmp_path):
    train = tmp_path / "train"
    _grow(train, rounds, [0])
    build_frame_encodings(_open(train), FINGERPRINT, CountingEncoder(), "cpu", batch_size=BATCH)
    path = cache_path(train, FINGERPRINT)
    old = _files(path)
    _grow(train, rounds, [1, 2])
    # a build killed earlier by a signal left its temporary directory behind (its process is gone)
    abandoned = path.parent / f".{path.name}.tmp-999999999"
    abandoned.mkdir()

    with pytest.raises(KeyboardInterrupt):
        build_frame_encodings(_open(train), FINGERPRINT, CountingEncoder(fail_on_call=2), "cpu", batch_size=BATCH)
    assert _files(path) == old
    assert sorted(entry.name for entry in path.parent.iterdir()) == [path.name]

    encoder = CountingEncoder()
    build_frame_encodings(_open(train), FINGERPRINT, encoder, "cpu", batch_size=BATCH)
    assert encoder.frames == 4 * NUM_FRAMES
    assert len(load_frame_encodings(train, FINGERPRINT)) == 8 * NUM_FRAMES
