"""The parallel shard merge writes exactly what LeRobot's serial ``aggregate_datasets`` writes, and fails safely."""

from __future__ import annotations

import dataclasses
import json
import multiprocessing
import shutil
from pathlib import Path

import numpy as np
import pytest

from lerobot_instant_policy.objects.rendering import RenderConfig
from lerobot_instant_policy.pseudo_demos import merge
from lerobot_instant_policy.pseudo_demos.generation import (
    DEMOS_FILE,
    SHARDS_DIR,
    TASKS_FILE,
    GenerationConfig,
    generate_dataset,
    generate_shard,
    merge_shards,
    prepare_output,
    shard_dir,
    shard_ranges,
    shard_repo_id,
)
from lerobot_instant_policy.pseudo_demos.replay import DemoConfig

REPO_ID = "local/test_merge"
_REAL_REWRITE = merge.rewrite_data_file


def _fail_on_second_file(job: merge.DataFileJob):
    """A worker that dies on the merged dataset's second data file (sent to spawned workers by reference)."""
    if job.destination.name == "file-001.parquet":
        raise RuntimeError("worker failed")
    return _REAL_REWRITE(job)


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """A generation interrupted after its shards: 5 reach tasks × 2 demos (256 surface points) in 3 shards."""
    out = tmp_path_factory.mktemp("merge") / "pseudo"
    config = GenerationConfig(
        out=str(out), repo_id=REPO_ID, num_tasks=5, demos_per_task=2, tasks_per_shard=2, family="reach",
        render=RenderConfig(cloud="surface"), demo=DemoConfig(num_points=256),
    )
    prepare_output(config, overwrite=False, resume=False)
    for index, tasks in enumerate(shard_ranges(config)):
        generate_shard(config, index, tasks)
    return config


@pytest.fixture(scope="module")
def pool():
    with multiprocessing.get_context("spawn").Pool(2) as workers:
        yield workers


def _files(root: Path) -> dict[str, bytes]:
    return {str(path.relative_to(root)): path.read_bytes() for path in sorted(root.rglob("*")) if path.is_file()}


def test_parallel_merge_equals_lerobots_serial_aggregation(generated, pool, tmp_path):
    """Shards 0, 1, 2 and 0 again (so that task indices are remapped onto earlier tasks, not only offset)."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.data.context_bank import ContextBank

    order = [0, 1, 2, 0]
    roots = [shard_dir(generated, index) for index in order]
    repo_ids = [shard_repo_id(generated, index) for index in order]
    merge.merge_serial(roots, repo_ids, REPO_ID, tmp_path / "serial")
    merge.merge_parallel(roots, repo_ids, REPO_ID, tmp_path / "in_process")
    merge.merge_parallel(roots, repo_ids, REPO_ID, tmp_path / "pool", pool)

    reference = _files(tmp_path / "serial")
    assert sorted(reference) == [
        "data/chunk-000/file-000.parquet", "data/chunk-000/file-001.parquet", "data/chunk-000/file-002.parquet",
        "data/chunk-000/file-003.parquet", "meta/episodes/chunk-000/file-000.parquet", "meta/info.json",
        "meta/stats.json", "meta/tasks.parquet",
    ]
    # every file byte for byte, info.json included: it holds no path, so nothing is exempt
    assert _files(tmp_path / "in_process") == reference
    assert _files(tmp_path / "pool") == reference

    serial = LeRobotDataset(REPO_ID, root=tmp_path / "serial")
    parallel = LeRobotDataset(REPO_ID, root=tmp_path / "pool")
    assert parallel.meta.info.to_dict() == serial.meta.info.to_dict()
    assert parallel.meta.total_episodes == 14 and parallel.meta.total_frames == len(parallel.hf_dataset)
    assert parallel.meta.tasks.equals(serial.meta.tasks) and len(parallel.meta.tasks) == 5
    assert parallel.meta.episodes.to_pandas().equals(serial.meta.episodes.to_pandas())
    for key, stats in serial.meta.stats.items():
        for name, value in stats.items():
            np.testing.assert_allclose(parallel.meta.stats[key][name], value)
    for column in serial.hf_dataset.column_names:
        np.testing.assert_array_equal(
            np.asarray(parallel.hf_dataset.with_format("numpy")[column]),
            np.asarray(serial.hf_dataset.with_format("numpy")[column]),
        )
    assert parallel.features["observation.pointcloud"]["shape"] == (256, 3)
    assert tuple(parallel[0]["observation.pointcloud"].shape) == (256, 3)
    # the repeated shard 0 (episodes 10-13) takes task indices 0 and 1 again, after the 10 episodes of shards 0-2
    frames = parallel.hf_dataset.with_format("numpy")
    repeated = frames[int(parallel.meta.episodes["dataset_from_index"][10])]
    assert (int(repeated["episode_index"]), int(repeated["task_index"])) == (10, 0)
    assert sorted(set(np.asarray(frames["task_index"]).tolist())) == [0, 1, 2, 3, 4]
    bank = ContextBank.from_dataset(REPO_ID, tmp_path / "pool", num_waypoints=10)
    assert len(bank) == 14 and bank.task_of_row[:4] == bank.task_of_row[10:14]


def test_interrupted_merge_keeps_the_shards_and_resume_completes(generated, pool, tmp_path, monkeypatch):
    """A worker dies during the merge: the shards are untouched, no half dataset is in place, and a resumed run
    with one worker (merging in-process) writes LeRobot's serial aggregation byte for byte."""
    out = tmp_path / "pseudo"
    shutil.copytree(generated.out, out)
    config = dataclasses.replace(generated, out=str(out), workers=2)
    shards_before = _files(out / SHARDS_DIR)

    monkeypatch.setattr(merge, "rewrite_data_file", _fail_on_second_file)
    with pytest.raises(RuntimeError, match="worker failed"):
        merge_shards(config, pool=pool)
    monkeypatch.undo()
    assert _files(out / SHARDS_DIR) == shards_before
    assert not (out / "data").exists() and not (out / "meta").exists()

    assert generate_dataset(dataclasses.replace(config, workers=1), resume=True, progress=False) == out
    assert sorted(path.name for path in out.iterdir()) == ["data", "meta"]
    indices = range(len(shard_ranges(config)))
    merge.merge_serial(
        [shard_dir(generated, index) for index in indices], [shard_repo_id(generated, index) for index in indices],
        REPO_ID, tmp_path / "serial",
    )
    written = _files(out)
    for name in (TASKS_FILE, DEMOS_FILE):
        lines = written.pop(f"meta/{name}").decode().splitlines()
        shards = [(shard_dir(generated, index) / "meta" / name).read_text().splitlines() for index in indices]
        assert lines == sum(shards, [])
    assert written == _files(tmp_path / "serial")
    scenes = [json.loads(line) for line in (out / "meta" / DEMOS_FILE).read_text().splitlines()]
    assert len(scenes) == 10
