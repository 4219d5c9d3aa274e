"""Speed of pseudo-demonstration generation: rendered frames and demonstrations per second, and the shard merges.

:func:`bench_generate` times rendering (sampling, replay, rendering, resampling) in one worker process and in
``workers`` processes at once (medians over ``repeats`` runs); with ``merge_tasks`` > 0 also ``generate_dataset`` end
to end (render, write shards, merge) with one worker and with ``workers``, and, on the same shards, LeRobot's serial
``aggregate_datasets`` against the parallel merge (in one process, and with a warm pool of ``workers``).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import statistics
import time


def _generate_worker(job: tuple[int, int, int]) -> tuple[int, int, float]:
    """Generate ``tasks`` pseudo-tasks of seed ``seed`` from ``first``; returns (frames, demos, seconds)."""
    seed, first, tasks = job
    from ..objects.rendering import PointCloudRenderer
    from ..pseudo_demos.generation import GenerationConfig, generate_task

    config = GenerationConfig(seed=seed, demos_per_task=2)
    frames = demos = 0
    with PointCloudRenderer(config.render) as renderer:
        generate_task(config, first, renderer)
        start = time.perf_counter()
        for task_index in range(first + 1, first + 1 + tasks):
            _, rendered = generate_task(config, task_index, renderer)
            frames += sum(demo.num_frames for demo in rendered)
            demos += len(rendered)
    return frames, demos, time.perf_counter() - start


def bench_generate(tasks: int, workers: int, repeats: int, merge_tasks: int = 0, tasks_per_shard: int = 2) -> dict:
    """Frames/s and demos/s of rendering pseudo-demonstrations (sampling, replay, rendering, resampling); with
    ``merge_tasks`` > 0 also the end-to-end and merge figures of :func:`_bench_end_to_end` under ``"end_to_end"``."""
    context = multiprocessing.get_context("spawn")
    single, parallel, parallel_demos, single_demos = [], [], [], []
    with context.Pool(workers) as pool:
        for repeat in range(repeats):
            frames, demos, seconds = pool.apply(_generate_worker, ((repeat, 0, tasks),))
            single.append(frames / seconds)
            single_demos.append(demos / seconds)
            start = time.perf_counter()
            results = pool.map(_generate_worker, [(repeat, 1000 * worker, tasks) for worker in range(workers)])
            wall = time.perf_counter() - start
            parallel.append(sum(result[0] for result in results) / wall)
            parallel_demos.append(sum(result[1] for result in results) / wall)
    result = {
        "benchmark": "generate",
        "tasks_per_run": tasks,
        "demos_per_task": 2,
        "repeats": repeats,
        "cpu_count": os.cpu_count(),
        "frames_per_s_one_worker": round(statistics.median(single), 1),
        "demos_per_s_one_worker": round(statistics.median(single_demos), 3),
        "workers": workers,
        "frames_per_s_total": round(statistics.median(parallel), 1),
        "frames_per_s_per_worker": round(statistics.median(parallel) / workers, 1),
        "demos_per_s_total": round(statistics.median(parallel_demos), 3),
        "runs_frames_per_s_one_worker": [round(value, 1) for value in single],
        "runs_frames_per_s_total": [round(value, 1) for value in parallel],
    }
    if merge_tasks > 0:
        result["end_to_end"] = _bench_end_to_end(merge_tasks, tasks_per_shard, workers, repeats)
    return result


def _bench_end_to_end(tasks: int, tasks_per_shard: int, workers: int, repeats: int) -> dict:
    """``generate_dataset`` of ``tasks`` tasks (2 demos each) with 1 and ``workers`` workers (frames/s, render + merge,
    process start-up included), then merges of the last run's shards: LeRobot's serial ``aggregate_datasets``
    (``merge_serial``), ``merge_parallel`` in this process, and ``merge_parallel`` with a warm pool of ``workers``."""
    import tempfile
    from pathlib import Path

    from ..pseudo_demos.generation import GenerationConfig, generate_dataset, shard_dir, shard_ranges, shard_repo_id
    from ..pseudo_demos.merge import merge_parallel, merge_serial

    end_to_end: dict[int, list[float]] = {1: [], workers: []}
    merges: dict[str, list[float]] = {"serial": [], "parallel_one_process": [], "parallel_pool": []}
    with tempfile.TemporaryDirectory(prefix="bench-merge-") as scratch:
        for repeat in range(repeats):
            for count in end_to_end:
                config = GenerationConfig(out=f"{scratch}/e2e-{repeat}-{count}", repo_id="local/bench", num_tasks=tasks,
                                          demos_per_task=2, tasks_per_shard=tasks_per_shard, seed=repeat, workers=count)
                start = time.perf_counter()
                out = generate_dataset(config, keep_shards=True, progress=False)
                seconds = time.perf_counter() - start
                frames = json.loads((out / "meta" / "info.json").read_text())["total_frames"]
                end_to_end[count].append(frames / seconds)
        shards = [shard_dir(config, index) for index in range(len(shard_ranges(config)))]
        repo_ids = [shard_repo_id(config, index) for index in range(len(shards))]
        with multiprocessing.get_context("spawn").Pool(min(workers, len(shards))) as pool:
            for repeat in range(-1, repeats):  # round -1 warms the workers' imports and the file cache, untimed
                for name, merge in (
                    ("serial", lambda root: merge_serial(shards, repo_ids, "local/bench", root)),
                    ("parallel_one_process", lambda root: merge_parallel(shards, repo_ids, "local/bench", root)),
                    ("parallel_pool", lambda root: merge_parallel(shards, repo_ids, "local/bench", root, pool)),
                ):
                    start = time.perf_counter()
                    merge(Path(scratch) / f"merge-{repeat}-{name}")
                    if repeat >= 0:
                        merges[name].append(time.perf_counter() - start)
    median = {name: statistics.median(values) for name, values in merges.items()}
    return {
        "tasks": tasks,
        "frames": frames,
        "shards": len(shards),
        "frames_per_s_one_worker": round(statistics.median(end_to_end[1]), 1),
        "frames_per_s_workers": round(statistics.median(end_to_end[workers]), 1),
        "speedup_workers_over_one": round(statistics.median(end_to_end[workers]) / statistics.median(end_to_end[1]), 2),
        "merge_s_serial_lerobot": round(median["serial"], 3),
        "merge_s_parallel_one_process": round(median["parallel_one_process"], 3),
        "merge_s_parallel_pool": round(median["parallel_pool"], 3),
        "merge_speedup_one_process": round(median["serial"] / median["parallel_one_process"], 2),
        "merge_speedup_pool": round(median["serial"] / median["parallel_pool"], 2),
        "runs_merge_s": {name: [round(value, 3) for value in values] for name, values in merges.items()},
        "runs_frames_per_s": {str(count): [round(value, 1) for value in values] for count, values in end_to_end.items()},
    }
