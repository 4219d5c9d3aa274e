"""``lerobot-ip-bench``: measured speed on this machine of what a user runs, printed as JSON.

``lerobot-ip-bench generate``: rendered pseudo-demonstration frames per second, for one worker process and for
``--workers`` processes at once (medians over ``--repeats`` runs), and demonstrations per second. With
``--merge-tasks K``: also frames per second end to end (``generate_dataset``: render, write shards, merge) of K tasks
with one worker and with ``--workers``, and, on the same shards, LeRobot's serial ``aggregate_datasets`` against the
parallel merge (in one process, and with a warm pool of ``--workers``), medians and ratios.
``lerobot-ip-bench env``: ``bullet_tabletop`` steps per second with point-cloud observations, one render's time.
``lerobot-ip-bench metaworld-env``: LeRobot's MetaWorld env (``metaworld_pointcloud``, the ``metaworld`` extra) steps
per second with clouds every step and every ``--pointcloud-every`` steps, one cloud's time.
``lerobot-ip-bench inference --preset small|paper``: ``instant_policy`` milliseconds per control step (K=4, N=2,
L=10, T=8, 2048 points, batch 1, demo context cached). ``lerobot-ip-bench train-step --preset small|paper``:
training samples per second and peak RSS, with the frames' scene nodes read from frame encodings as
``lerobot-train`` does (``--frame-cache false``: encoded live). Both time one setting: ``--dense-attention
true|false`` (σ and ψ in the dense layout or the torch-geometric reference layers), the model variant flags
(``--reencode-action-clouds``, ``--action-scene-graph``, ``--num-frequencies``); ``inference`` also
``--compile-inference true|false`` (σ, φ and ψ through ``torch.compile`` for sampling), ``train-step`` also
``--compile-model true|false`` (the same for the training step), ``--amp`` and ``--fused-adamw``; both report the
compiling as ``warmup_s``.
``lerobot-ip-bench stream|pool --config CONFIG``: training on fresh pseudo-tasks from the stream (rendered in the
update's process) or from the rolling pool of encoded tasks (``--generators`` processes): samples and fresh tasks per
second by wall time over the whole run, every render inside it, and the pool's uses per task (``benchmarks.stream``).
The benchmarks themselves are :mod:`lerobot_instant_policy.benchmarks`. The repository's development benchmarks
(the geometry encoder alone, a training row's data, ``lerobot-train`` end to end, and two settings of ``inference``
or ``train-step`` timed in alternation with their ratio, ``--compare-*``) are ``python -m workbench.cli.bench`` in a
clone, not installed; it builds on this module's parsers (:func:`add_inference_arguments`,
:func:`add_train_step_arguments`) and :func:`run`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

# Each subcommand imports its benchmark when it runs: the generation benchmark's spawned workers import this module
# again, and should not pay for torch and the policy.

JSON_HELP = "print JSON only (the default output is JSON too)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-bench", description="Benchmarks that print JSON.")
    commands = parser.add_subparsers(dest="command", required=True)
    for add in (_add_generate, _add_env, _add_metaworld_env, _add_inference, _add_train_step, _add_stream):
        add(commands)
    return parser


def run(parser: argparse.ArgumentParser, argv: list[str] | None = None) -> int:
    """Parse ``argv`` with a parser of benchmark subcommands (each sets ``handler``) and print its result as JSON."""
    args = parser.parse_args(argv)
    result = args.handler(parser, args)
    print(json.dumps(result, indent=None if args.json else 2))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run(build_parser(), argv)


# ---------------------------------------------------------------------------------------------------- generate
def _add_generate(commands) -> None:
    generate = commands.add_parser("generate", help="pseudo-demonstration rendering speed")
    generate.add_argument("--tasks", type=int, default=3, help="pseudo-tasks (2 demos each) per worker and run")
    generate.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    generate.add_argument("--repeats", type=int, default=3)
    generate.add_argument("--merge-tasks", type=int, default=0,
                          help="also generate this many tasks end to end (render + merge) and time the merges")
    generate.add_argument("--tasks-per-shard", type=int, default=2, help="shard size of the --merge-tasks runs")
    generate.add_argument("--json", action="store_true", help=JSON_HELP)
    generate.set_defaults(handler=_run_generate)


def _run_generate(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if min(args.tasks, args.workers, args.repeats, args.tasks_per_shard) <= 0 or args.merge_tasks < 0:
        parser.error("--tasks, --workers, --repeats and --tasks-per-shard must be positive, --merge-tasks >= 0")
    from ..benchmarks.generation import bench_generate

    return bench_generate(args.tasks, args.workers, args.repeats, args.merge_tasks, args.tasks_per_shard)


# ---------------------------------------------------------------------------------------------------- env
def _add_env(commands) -> None:
    env = commands.add_parser("env", help="bullet_tabletop env steps per second with point-cloud observations")
    env.add_argument("--task", default="pick_and_place")
    env.add_argument("--steps", type=int, default=60)
    env.add_argument("--repeats", type=int, default=3)
    env.add_argument("--video-sizes", type=int, nargs="+", default=[256, 64],
                     help="also time one render() video frame at each of these square sizes (--env.render_size)")
    env.add_argument("--json", action="store_true", help=JSON_HELP)
    env.set_defaults(handler=_run_env)


def _run_env(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if min(args.steps, args.repeats, *args.video_sizes) <= 0:
        parser.error("--steps, --repeats and --video-sizes must be positive")
    from ..benchmarks.env import bench_env

    return bench_env(args.task, args.steps, args.repeats, tuple(args.video_sizes))


def _add_metaworld_env(commands) -> None:
    env = commands.add_parser("metaworld-env", help="MetaWorld env steps per second with point-cloud observations")
    env.add_argument("--task", default="pick-place-v3")
    env.add_argument("--steps", type=int, default=40)
    env.add_argument("--repeats", type=int, default=3)
    env.add_argument("--pointcloud-every", type=int, default=8)
    env.add_argument("--json", action="store_true", help=JSON_HELP)
    env.set_defaults(handler=_run_metaworld_env)


def _run_metaworld_env(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if min(args.steps, args.repeats, args.pointcloud_every) <= 0:
        parser.error("--steps, --repeats and --pointcloud-every must be positive")
    from ..benchmarks.metaworld import bench_metaworld_env

    return bench_metaworld_env(args.task, args.steps, args.repeats, args.pointcloud_every)


# ---------------------------------------------------------------------------------------------------- inference
def _add_inference(commands) -> None:
    inference = commands.add_parser("inference", help="instant_policy milliseconds per control step")
    add_inference_arguments(inference)
    inference.set_defaults(handler=_run_inference)


def add_inference_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``inference`` (read back by :func:`inference_settings`)."""
    parser.add_argument("--preset", choices=["small", "paper", "refined"], default="small")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--policy-path", help="time this checkpoint (a pretrained_model directory) instead of a fresh preset")
    _add_variant_arguments(parser)
    parser.add_argument("--compile-inference", choices=["true", "false"],
                        help="σ, φ and ψ through torch.compile for sampling (--policy.compile_inference; default "
                             "false); the first control step, which compiles, is reported as warmup_s")
    parser.add_argument("--samples-per-prediction", type=int,
                        help="predict the mean of this many samples (--policy.samples_per_prediction; default 1)")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def inference_settings(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    """The options and config overrides of ``bench_inference`` that ``args`` give; a usage error for bad sizes."""
    if args.repeats <= 0:
        parser.error("--repeats must be positive")
    settings = _variant_settings(args)
    if args.compile_inference is not None:
        settings["compile_inference"] = args.compile_inference == "true"
    if args.samples_per_prediction is not None:
        if args.samples_per_prediction <= 0:
            parser.error("--samples-per-prediction must be positive")
        settings["samples_per_prediction"] = args.samples_per_prediction
    return settings


def _run_inference(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    settings = inference_settings(parser, args)
    from ..benchmarks.policy import bench_inference

    return bench_inference(args.preset, repeats=args.repeats, policy_path=args.policy_path, **settings)


# ---------------------------------------------------------------------------------------------------- train-step
def _add_train_step(commands) -> None:
    train_step = commands.add_parser("train-step", help="instant_policy training samples per second, peak memory")
    add_train_step_arguments(train_step)
    train_step.set_defaults(handler=_run_train_step)


def add_train_step_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``train-step`` (read back by :func:`train_step_settings`)."""
    parser.add_argument("--preset", choices=["small", "paper", "refined"], default="small")
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    _add_variant_arguments(parser)
    parser.add_argument("--frame-cache", choices=["true", "false"], default="true",
                        help="scene nodes of every frame from precomputed frame encodings (lerobot-train's path)")
    parser.add_argument("--amp", choices=["true", "false"], default="false",
                        help="forward under autocast (bfloat16 on the CPU), as --policy.use_amp=true trains")
    parser.add_argument("--fused-adamw", choices=["true", "false"],
                        help="AdamW's fused kernel (default: the preset's, fused on the CPU and CUDA)")
    parser.add_argument("--compile-model", choices=["true", "false"],
                        help="σ, φ and ψ through torch.compile (--policy.compile_model; default false); the "
                             "compiling is timed as warmup_s, outside samples_per_s")
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


def train_step_settings(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    """The options and config overrides of ``bench_train_step`` that ``args`` give (batch size and repeats aside); a
    usage error for bad sizes."""
    if min(args.repeats, args.batch_size) <= 0:
        parser.error("--repeats and --batch-size must be positive")
    settings = _variant_settings(args)
    settings["frame_cache"] = args.frame_cache == "true"
    settings["use_amp"] = args.amp == "true"
    settings.update(_given_flags(args, ("fused_adamw", "compile_model")))
    return settings


def _run_train_step(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    settings = train_step_settings(parser, args)
    from ..benchmarks.policy import bench_train_step

    return bench_train_step(args.preset, batch_size=args.batch_size, repeats=args.repeats, **settings)


def _add_variant_arguments(parser: argparse.ArgumentParser) -> None:
    """The model-variant flags of ``inference`` and ``train-step`` (read back by :func:`_variant_settings`)."""
    parser.add_argument("--reencode-action-clouds", choices=["true", "false"],
                        help="override the config (default: false, the shipped model; the paper's: true)")
    parser.add_argument("--dense-attention", choices=["true", "false"],
                        help="σ, φ and ψ in the dense layout (default: true) or the torch-geometric reference")
    parser.add_argument("--action-scene-graph", choices=["true", "false"],
                        help="override the config (default: false, the shipped model; true: the paper's graph)")
    parser.add_argument("--num-frequencies", type=int,
                        help="edge-encoding frequencies D (default: 4, the shipped model; the paper's: 10)")


def _variant_settings(args: argparse.Namespace) -> dict:
    """Config overrides from ``--reencode-action-clouds``, ``--action-scene-graph``, ``--num-frequencies`` and
    ``--dense-attention``, the flags given."""
    return _given_flags(args, ("reencode_action_clouds", "action_scene_graph", "num_frequencies", "dense_attention"))


def _given_flags(args: argparse.Namespace, names: tuple[str, ...]) -> dict:
    """``{name: value}`` for each of ``names`` given on the command line; ``true``/``false`` become booleans."""
    values = {name: getattr(args, name) for name in names if getattr(args, name) is not None}
    return {name: value == "true" if value in ("true", "false") else value for name, value in values.items()}


# ---------------------------------------------------------------------------------------------------- stream, pool
def _add_stream(commands) -> None:
    for name, help_text in (
        ("stream", "training on the pseudo-task stream (every cloud rendered and encoded in the update's process): "
                   "samples and fresh tasks per second by wall time over the whole run"),
        ("pool", "training on the rolling pool of encoded fresh tasks (generator processes render and encode): "
                 "samples and fresh tasks per second by wall time over the whole run, uses per task"),
    ):
        command = commands.add_parser(name, help=help_text)
        command.add_argument("--config", default="configs/generate/stream_bounded.json",
                             help="a lerobot-ip-generate JSON config: the distributions the tasks are drawn from")
        command.add_argument("--preset", choices=["small", "paper", "refined"], default="small",
                             help="the instant_policy preset (width) whose update is fed")
        command.add_argument("--batch-size", type=int, default=8)
        command.add_argument("--seconds", type=float, default=600.0 if name == "pool" else 60.0,
                             help="wall time of the run (it stops earlier at --steps)")
        command.add_argument("--steps", type=int, help="stop after this many updates")
        command.add_argument("--samples-per-task", type=int, default=8 if name == "pool" else 1,
                             help="live frames per task (the stream: samples per task; the pool: frames encoded per "
                                  "task, of which each sample draws one)")
        command.add_argument("--tasks-per-render", type=int, help="tasks rendered in one batched call (default: "
                                                                  "the stream's)")
        command.add_argument("--zbuffer", type=int, nargs=2, metavar=("W", "H"),
                             help="splatting z-buffer size (default: the stream's 480 360)")
        command.add_argument("--surface-samples", type=int,
                             help="surface samples per object that splatting draws from (default: the stream's 8192)")
        command.add_argument("--threads", type=int, help="torch threads of the update (default: torch's)")
        command.add_argument("--device", help="the update's device (default: cuda when there is one, else cpu)")
        if name == "pool":  # default: PoolConfig's
            command.add_argument("--generators", type=int, help="generator processes")
            command.add_argument("--generator-threads", type=int, help="torch threads per generator")
            command.add_argument("--generator-device", help="where generators render and encode: cpu or cuda")
            command.add_argument("--capacity", type=int, help="tasks held, the oldest replaced")
            command.add_argument("--min-tasks", type=int, help="tasks received before the first sample")
        command.add_argument("--json", action="store_true", help=JSON_HELP)
        command.set_defaults(handler=_run_stream)
    priors = commands.add_parser("priors", help="what replay priors (training to refine) cost a pool generator: "
                                               "seconds per task without and with them, interleaved, and the ratio")
    priors.add_argument("--config", default="configs/generate/stream_bounded_mixed.json",
                        help="a lerobot-ip-generate JSON config: the distributions the tasks are drawn from")
    priors.add_argument("--tasks", type=int, default=24, help="tasks per variant")
    priors.add_argument("--samples-per-task", type=int, default=8, help="live frames rendered and encoded per task")
    priors.add_argument("--tasks-per-render", type=int, default=1,
                        help="tasks rendered in one call (one block; default: the standing run's 1)")
    priors.add_argument("--surface-samples", type=int, default=4096,
                        help="surface samples per object that splatting draws from (default: the standing run's 4096)")
    priors.add_argument("--threads", type=int, default=1, help="torch threads (a pool generator's default: 1)")
    priors.add_argument("--json", action="store_true", help=JSON_HELP)
    priors.set_defaults(handler=_run_priors)


def _run_stream(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    sizes = [args.batch_size, args.samples_per_task, args.tasks_per_render, args.steps, args.threads,
             args.surface_samples]
    if min(size for size in sizes if size is not None) <= 0 or args.seconds < 0:
        parser.error("--batch-size, --samples-per-task, --tasks-per-render, --steps, --threads and --seconds must be "
                     "positive")
    import torch

    from ..benchmarks.stream import pool_benchmark, stream_benchmark
    from ..pseudo_demos.stream import StreamConfig

    if args.threads:
        torch.set_num_threads(args.threads)
    overrides = {"samples_per_task": args.samples_per_task}
    if args.tasks_per_render:
        overrides["tasks_per_render"] = args.tasks_per_render
    if args.zbuffer:
        overrides["zbuffer_resolution"] = tuple(args.zbuffer)
    if args.surface_samples:
        overrides["surface_samples"] = args.surface_samples
    config = StreamConfig.from_generate_config(args.config, **overrides)
    run = dict(preset=args.preset, batch_size=args.batch_size, seconds=args.seconds, steps=args.steps,
               device=args.device)
    if args.command == "stream":
        return stream_benchmark(config, **run)
    from ..training.task_pool import PoolConfig

    chosen = {"capacity": args.capacity, "min_tasks": args.min_tasks, "generators": args.generators,
              "generator_threads": args.generator_threads, "device": args.generator_device}
    try:
        pool = PoolConfig(stream=config, **{key: value for key, value in chosen.items() if value is not None})
    except ValueError as error:
        parser.error(str(error))
    return pool_benchmark(config, pool, **run)


def _run_priors(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    if min(args.tasks, args.samples_per_task, args.tasks_per_render, args.surface_samples, args.threads) <= 0:
        parser.error("--tasks, --samples-per-task, --tasks-per-render, --surface-samples and --threads must be "
                     "positive")
    import torch

    from ..benchmarks.stream import replay_prior_benchmark
    from ..pseudo_demos.stream import StreamConfig

    torch.set_num_threads(args.threads)
    config = StreamConfig.from_generate_config(args.config, samples_per_task=args.samples_per_task,
                                               tasks_per_render=args.tasks_per_render,
                                               surface_samples=args.surface_samples)
    return replay_prior_benchmark(config, tasks=args.tasks)


if __name__ == "__main__":
    sys.exit(main())
