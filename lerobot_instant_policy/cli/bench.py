"""``lerobot-ip-bench``: measured speed of the project's parts, printed as JSON.

``lerobot-ip-bench generate``: rendered pseudo-demonstration frames per second, for one worker process and for
``--workers`` processes at once (medians over ``--repeats`` runs), and demonstrations per second. With
``--merge-tasks K``: also frames per second end to end (``generate_dataset``: render, write shards, merge) of K tasks
with one worker and with ``--workers``, and, on the same shards, LeRobot's serial ``aggregate_datasets`` against the
parallel merge (in one process, and with a warm pool of ``--workers``), medians and ratios.
``lerobot-ip-bench encoder``: geometry-encoder clouds per second at 2048 points, batch 1 and 16, both presets.
``lerobot-ip-bench env``: ``bullet_tabletop`` steps per second with point-cloud observations, one render's time.
``lerobot-ip-bench inference --preset small|paper``: ``instant_policy`` milliseconds per control step (K=4, N=2,
L=10, T=8, 2048 points, batch 1, demo context cached). ``lerobot-ip-bench train-step --preset small|paper``:
training samples per second and peak RSS, with the frames' scene nodes read from frame encodings as
``lerobot-train`` does (``--frame-cache false``: encoded live; ``--compare-frame-cache``: both, and their ratio).
Both take ``--dense-attention true|false`` (σ and ψ in the dense layout or
the torch-geometric reference layers) and ``--compare-dense-attention``, which times both in alternation in one run
and reports their ratio; ``inference`` also ``--compile-inference true|false`` (σ, φ and ψ through ``torch.compile``
for sampling) and ``--compare-compile-inference``; ``train-step`` also ``--compile-model true|false`` (σ, φ and ψ
through ``torch.compile`` for the training step) and ``--compare-compile-model``; both report the compiling as
``warmup_s``.
``lerobot-ip-bench lerobot-train --root DIR``: ``lerobot-train``'s own samples per second on a dataset, end to end
(data loader, LeRobot's loop, the update), for each ``--num-workers`` and ``--omp-wait-policy`` in alternation.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import sys
import time


def _generate_worker(job: tuple[int, int, int]) -> tuple[int, int, float]:
    """Generate ``tasks`` pseudo-tasks of seed ``seed`` from ``first``; returns (frames, demos, seconds)."""
    seed, first, tasks = job
    from ..pseudo_demos.generation import GenerationConfig, generate_task
    from ..pseudo_demos.rendering import PointCloudRenderer

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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-bench", description="Benchmarks that print JSON.")
    commands = parser.add_subparsers(dest="command", required=True)
    generate = commands.add_parser("generate", help="pseudo-demonstration rendering speed")
    generate.add_argument("--tasks", type=int, default=3, help="pseudo-tasks (2 demos each) per worker and run")
    generate.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    generate.add_argument("--repeats", type=int, default=3)
    generate.add_argument("--merge-tasks", type=int, default=0,
                          help="also generate this many tasks end to end (render + merge) and time the merges")
    generate.add_argument("--tasks-per-shard", type=int, default=2, help="shard size of the --merge-tasks runs")
    generate.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    encoder = commands.add_parser("encoder", help="geometry encoder clouds per second (2048 points, CPU)")
    encoder.add_argument("--repeats", type=int, default=5)
    encoder.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    env = commands.add_parser("env", help="bullet_tabletop env steps per second with point-cloud observations")
    env.add_argument("--task", default="pick_and_place")
    env.add_argument("--steps", type=int, default=60)
    env.add_argument("--repeats", type=int, default=3)
    env.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    inference = commands.add_parser("inference", help="instant_policy milliseconds per control step")
    inference.add_argument("--preset", choices=["small", "paper"], default="small")
    inference.add_argument("--repeats", type=int, default=5)
    inference.add_argument("--policy-path", help="time this checkpoint (a pretrained_model directory) instead of a fresh preset")
    _add_variant_arguments(inference)
    inference.add_argument("--compile-inference", choices=["true", "false"],
                           help="σ, φ and ψ through torch.compile for sampling (--policy.compile_inference; default "
                                "false); the first control step, which compiles, is reported as warmup_s")
    inference.add_argument("--compare-compile-inference", action="store_true",
                           help="time compiled and eager sampling in alternation and report the ratio")
    inference.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    train_step = commands.add_parser("train-step", help="instant_policy training samples per second, peak memory")
    train_step.add_argument("--preset", choices=["small", "paper"], default="small")
    train_step.add_argument("--batch-size", type=int, default=8)
    train_step.add_argument("--repeats", type=int, default=5)
    _add_variant_arguments(train_step)
    train_step.add_argument("--frame-cache", choices=["true", "false"], default="true",
                            help="scene nodes of every frame from precomputed frame encodings (lerobot-train's path)")
    train_step.add_argument("--compare-frame-cache", action="store_true",
                            help="time cached and live encoding in alternation and report the ratio")
    train_step.add_argument("--amp", choices=["true", "false"], default="false",
                            help="forward under autocast (bfloat16 on the CPU), as --policy.use_amp=true trains")
    train_step.add_argument("--compare-amp", action="store_true",
                            help="time autocast and float32 in alternation and report the ratio")
    train_step.add_argument("--fused-adamw", choices=["true", "false"],
                            help="AdamW's fused kernel (default: the preset's, fused on the CPU and CUDA)")
    train_step.add_argument("--compare-fused-adamw", action="store_true",
                            help="time fused and loop AdamW in alternation and report the ratio")
    train_step.add_argument("--compile-model", choices=["true", "false"],
                            help="σ, φ and ψ through torch.compile (--policy.compile_model; default false); the "
                                 "compiling is timed as warmup_s, outside samples_per_s")
    train_step.add_argument("--compare-compile-model", action="store_true",
                            help="time compiled and eager layers in alternation and report the ratio")
    train_step.add_argument("--noise-draws", type=int,
                            help="diffusion draws per sample (--policy.noise_draws; samples/s counts samples)")
    train_step.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    data = commands.add_parser("data", help="milliseconds per training row: LeRobot's delta timestamps against the "
                                            "policy's action table")
    data.add_argument("--root", required=True, help="a LeRobotDataset in the data contract")
    data.add_argument("--repo-id", required=True)
    data.add_argument("--rows", type=int, default=200)
    data.add_argument("--horizon", type=int, default=8)
    data.add_argument("--repeats", type=int, default=3)
    data.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    train = commands.add_parser("lerobot-train", help="lerobot-train's own samples per second on a dataset (loader, "
                                                      "loop and update), per loader workers and OpenMP wait policy")
    train.add_argument("--root", required=True, help="a LeRobotDataset in the data contract (frame encodings are "
                                                     "built beside it by the first run when missing)")
    train.add_argument("--repo-id", help="default: local/<the root's name>")
    train.add_argument("--steps", type=int, default=500, help="training steps per run")
    train.add_argument("--skip", type=int, default=200, help="log lines up to this step do not count (warm-up)")
    train.add_argument("--log-every", type=int, default=50, help="--log_freq of each run")
    train.add_argument("--batch-size", type=int, default=8)
    train.add_argument("--threads", type=int, default=2, help="OMP_NUM_THREADS of each run")
    train.add_argument("--num-workers", type=int, nargs="+", default=[1], help="loader workers to compare")
    train.add_argument("--omp-wait-policy", nargs="+", default=["default"], choices=["default", "active", "passive"],
                       help="OMP_WAIT_POLICY values to compare (default: unset)")
    train.add_argument("--compile-model", choices=["true", "false"], default="false",
                       help="--policy.compile_model of every run (compiling falls within --skip)")
    train.add_argument("--rounds", type=int, default=1, help="every variant runs this many times, in alternation")
    train.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    args = parser.parse_args(argv)
    if args.command == "inference":
        if args.repeats <= 0:
            parser.error("--repeats must be positive")
        from .bench_policy import bench_inference, compare_variants

        if args.compare_dense_attention and args.compare_compile_inference:
            parser.error("compare one variant at a time: --compare-dense-attention or --compare-compile-inference")

        def run(**variant):
            fixed = {}
            if not args.compare_compile_inference and args.compile_inference is not None:
                fixed["compile_inference"] = args.compile_inference == "true"
            return bench_inference(args.preset, repeats=args.repeats, policy_path=args.policy_path,
                                   **_overrides(args), **fixed, **variant)

        if args.compare_dense_attention:
            result = compare_variants(run, "ms_per_control_step", "dense_attention", ("dense", "reference"))
        elif args.compare_compile_inference:
            result = compare_variants(run, "ms_per_control_step", "compile_inference", ("compiled", "eager"))
        else:
            result = run()
    elif args.command == "train-step":
        if min(args.repeats, args.batch_size, 1 if args.noise_draws is None else args.noise_draws) <= 0:
            parser.error("--repeats, --batch-size and --noise-draws must be positive")
        compares = (args.compare_dense_attention, args.compare_frame_cache, args.compare_amp,
                    args.compare_fused_adamw, args.compare_compile_model)
        if sum(compares) > 1:
            parser.error("compare one variant at a time: --compare-dense-attention, --compare-frame-cache, "
                         "--compare-amp, --compare-fused-adamw or --compare-compile-model")
        from .bench_policy import bench_train_step, compare_variants

        def run(**variant):
            fixed = {}
            if not args.compare_frame_cache:
                fixed["frame_cache"] = args.frame_cache == "true"
            if not args.compare_amp:
                fixed["use_amp"] = args.amp == "true"
            if not args.compare_fused_adamw and args.fused_adamw is not None:
                fixed["fused_adamw"] = args.fused_adamw == "true"
            if not args.compare_compile_model and args.compile_model is not None:
                fixed["compile_model"] = args.compile_model == "true"
            if args.noise_draws is not None:
                fixed["noise_draws"] = args.noise_draws
            return bench_train_step(args.preset, batch_size=args.batch_size, repeats=args.repeats, **_overrides(args),
                                    **fixed, **variant)

        if args.compare_dense_attention:
            result = compare_variants(run, "samples_per_s", "dense_attention", ("dense", "reference"))
        elif args.compare_frame_cache:
            result = compare_variants(run, "samples_per_s", "frame_cache", ("cached", "live"))
        elif args.compare_amp:
            result = compare_variants(run, "samples_per_s", "use_amp", ("amp", "float32"))
        elif args.compare_fused_adamw:
            result = compare_variants(run, "samples_per_s", "fused_adamw", ("fused", "loop"))
        elif args.compare_compile_model:
            result = compare_variants(run, "samples_per_s", "compile_model", ("compiled", "eager"))
        else:
            result = run()
    elif args.command == "lerobot-train":
        if min(args.steps, args.log_every, args.batch_size, args.threads, args.rounds) <= 0 or args.skip < 0 \
                or min(args.num_workers) < 0:
            parser.error("--steps, --log-every, --batch-size, --threads and --rounds must be positive, --skip and "
                         "--num-workers >= 0")
        if args.skip >= args.steps:
            parser.error(f"--skip ({args.skip}) must be below --steps ({args.steps})")
        from .bench_lerobot_train import bench_lerobot_train

        result = bench_lerobot_train(args.root, args.repo_id, args.steps, args.skip, args.batch_size, args.log_every,
                                     args.threads, tuple(args.num_workers), tuple(args.omp_wait_policy),
                                     args.compile_model == "true", args.rounds)
    elif args.command == "data":
        if min(args.rows, args.horizon, args.repeats) <= 0:
            parser.error("--rows, --horizon and --repeats must be positive")
        from .bench_data import bench_data

        result = bench_data(args.repo_id, args.root, args.rows, args.horizon, args.repeats)
    elif args.command == "env":
        if min(args.steps, args.repeats) <= 0:
            parser.error("--steps and --repeats must be positive")
        from .bench_env import bench_env

        result = bench_env(args.task, args.steps, args.repeats)
    elif args.command == "encoder":
        if args.repeats <= 0:
            parser.error("--repeats must be positive")
        from .bench_encoder import bench_encoder

        result = bench_encoder(repeats=args.repeats)
    elif args.command == "generate":
        if min(args.tasks, args.workers, args.repeats, args.tasks_per_shard) <= 0 or args.merge_tasks < 0:
            parser.error("--tasks, --workers, --repeats and --tasks-per-shard must be positive, --merge-tasks >= 0")
        result = bench_generate(args.tasks, args.workers, args.repeats, args.merge_tasks, args.tasks_per_shard)
    print(json.dumps(result, indent=None if args.json else 2))
    return 0


def _add_variant_arguments(parser: argparse.ArgumentParser) -> None:
    """The model-variant flags of ``inference`` and ``train-step`` (read back by :func:`_overrides`)."""
    parser.add_argument(
        "--reencode-action-clouds", choices=["true", "false"], help="override the config (default: the preset's)"
    )
    parser.add_argument("--dense-attention", choices=["true", "false"], help="override the config (default: true)")
    parser.add_argument("--action-scene-graph", choices=["true", "false"],
                        help="override the config (default: true, the paper's graph; make ladder: false)")
    parser.add_argument("--num-frequencies", type=int, help="edge-encoding frequencies D (default: 10; make ladder: 4)")
    parser.add_argument("--compare-dense-attention", action="store_true",
                        help="time dense and reference attention in alternation and report the ratio")


def _overrides(args) -> dict:
    """Config overrides from ``--reencode-action-clouds``, ``--action-scene-graph``, ``--num-frequencies`` and
    ``--dense-attention`` (the latter not when comparing)."""
    overrides = {}
    if args.reencode_action_clouds is not None:
        overrides["reencode_action_clouds"] = args.reencode_action_clouds == "true"
    if args.action_scene_graph is not None:
        overrides["action_scene_graph"] = args.action_scene_graph == "true"
    if args.num_frequencies is not None:
        overrides["num_frequencies"] = args.num_frequencies
    if args.dense_attention is not None and not args.compare_dense_attention:
        overrides["dense_attention"] = args.dense_attention == "true"
    return overrides


if __name__ == "__main__":
    sys.exit(main())
