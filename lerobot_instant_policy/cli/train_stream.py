"""``lerobot-ip-train``: ``lerobot-train`` on the pseudo-task stream (``training.stream_seam``): fresh pseudo-tasks drawn
and rendered as training goes, from the distributions of a ``lerobot-ip-generate`` config.

  lerobot-ip-train --stream.config configs/generate/train_large.json --policy.type=instant_policy \\
      --policy.device=cuda --batch_size=64 --steps=20000 --output_dir=outputs/train/stream
  lerobot-ip-train --stream.config configs/generate/train_large.json --stream.samples_per_task 8 \\
      --policy.type=instant_policy --policy.device=cpu --batch_size=8 --steps=200 --output_dir=outputs/train/cpu
  accelerate launch --num_processes 2 -m lerobot_instant_policy.cli.train_stream --stream.config ... (one stream
      per process)
  lerobot-ip-train --stream.config configs/generate/stream_bounded.json --pool --pool.generators 1 \
      --stream.samples_per_task 8 --policy.type=instant_policy --policy.device=cpu --batch_size=8 ... (the rolling
      pool of encoded fresh tasks: generator processes render and encode, the update reads encoded frames)

``--average.decay 0.999`` keeps a moving average of the trained weights beside the run (``training.weight_average``).
Every flag not of ``--stream.``, ``--pool`` or ``--average.`` goes to ``lerobot-train`` as it is (``--policy.*``,
``--steps``, ``--resume`` …); ``--dataset.*`` is the stream's.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

from ..pseudo_demos.stream import StreamConfig
from ..training.task_pool import PoolConfig


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-train", description=__doc__.split("\n\n")[0], allow_abbrev=False,
                                     epilog="every other flag goes to lerobot-train")
    parser.add_argument("--stream.config", dest="config", required=True,
                        help="a lerobot-ip-generate JSON config: the pseudo-task distributions (family, objects, "
                             "layouts, augmentations, seed)")
    parser.add_argument("--stream.samples_per_task", dest="samples_per_task", type=int,
                        help="live frames drawn per task (default 1: every sample from a task never drawn before; more "
                             "on a CPU, where rendering is dear)")
    parser.add_argument("--stream.tasks_per_render", dest="tasks_per_render", type=int,
                        help="tasks planned, then rendered in one batched call")
    parser.add_argument("--stream.surface_samples", dest="surface_samples", type=int,
                        help="surface samples per object that splatting draws the clouds from (default 8192)")
    parser.add_argument("--stream.seed", dest="seed", type=int, help="the stream's seed (default: the config's)")
    parser.add_argument("--stream.wrong_prior_keep", dest="wrong_prior_keep", type=float,
                        help="training to refine: the probability that a task whose replay prior is wrong keeps it "
                             "(default 1; the others train from noise)")
    parser.add_argument("--stream.prior_time_shift", dest="prior_time_shift", type=int,
                        help="training to refine: each replay prior read up to this many frames early or late, the "
                             "timing error of a robot that does not follow the plan exactly (default 0)")
    parser.add_argument("--pool", action="store_true",
                        help="draw from a rolling pool of encoded fresh tasks (training.task_pool) instead of rendering "
                             "in the update; --stream.samples_per_task is then the live frames encoded per task")
    defaults = PoolConfig()
    for name, help_text in (("capacity", "tasks held, the oldest replaced"),
                            ("min_tasks", "tasks received before the first sample"),
                            ("generators", "generator processes (each renders and encodes)"),
                            ("generator_threads", "torch threads per generator process"),
                            ("queue_size", "encoded tasks waiting between the generators and the pool")):
        parser.add_argument(f"--pool.{name}", dest=f"pool_{name}", type=int, default=getattr(defaults, name),
                            help=f"{help_text} (default {getattr(defaults, name)})")
    parser.add_argument("--pool.device", dest="pool_device", default=defaults.device,
                        help="where the generators render and encode: cpu or cuda (default cpu)")
    parser.add_argument("--average.decay", dest="average_decay", type=float,
                        help="keep a moving average of the trained weights with this decay in (0, 1), saved with each "
                             "checkpoint (training_state/weight_average.safetensors; default: none)")
    return parser


def pool_config_from_args(args: argparse.Namespace, stream_config: StreamConfig) -> PoolConfig | None:
    """The pool's config from ``--pool.*`` (None without ``--pool``); its stream and seed are set by the training."""
    if not args.pool:
        return None
    names = ("capacity", "min_tasks", "generators", "generator_threads", "queue_size", "device")
    return PoolConfig(stream=stream_config, **{name: getattr(args, f"pool_{name}") for name in names})


def stream_config_from_args(args: argparse.Namespace) -> StreamConfig:
    overrides = {name: getattr(args, name)
                 for name in ("samples_per_task", "tasks_per_render", "surface_samples", "wrong_prior_keep",
                              "prior_time_shift")
                 if getattr(args, name) is not None}
    config = StreamConfig.from_generate_config(args.config, **overrides)
    if args.seed is None:
        return config
    return dataclasses.replace(config, generation=dataclasses.replace(config.generation, seed=args.seed))


def main(argv: list[str] | None = None) -> int:
    from ..training.stream_seam import train

    parser = build_parser()
    args, lerobot_argv = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    try:
        config = stream_config_from_args(args)
        train(config, lerobot_argv, pool_config_from_args(args, config), args.average_decay)
    except (ValueError, FileNotFoundError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
