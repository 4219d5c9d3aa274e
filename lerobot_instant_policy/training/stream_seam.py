"""``lerobot-train`` on the pseudo-task stream (``pseudo_demos.stream``): LeRobot's own training loop, optimizer,
scheduler, checkpoints, resume, logging and accelerate, with every sample drawn from a task no earlier sample used.

LeRobot 0.6.1 builds its training data in ``lerobot.scripts.lerobot_train.train`` by calling
``make_train_eval_datasets(cfg)`` and hands the data loader to ``accelerator.prepare``; it has no hook for a dataset
of another kind. :func:`train` enters it at exactly two names for the stream (a third, ``save_checkpoint``, for the
task pool below) and nowhere else (the seam is tested against the pinned LeRobot version):

* ``make_train_eval_datasets`` returns a :class:`StreamDataset` (a ``torch`` ``IterableDataset`` with LeRobot's
  ``meta``, ``num_frames`` and ``num_episodes``) and no eval split; ``--dataset.streaming`` is set, so LeRobot uses
  no sampler and no shuffling. The stream's N, L, T and P come from the policy config (``max_demos``,
  ``num_waypoints``, ``horizon``, the clouds' size), so its batches are what the policy's training forward reads.
* ``accelerate.Accelerator`` is :class:`StreamAccelerator`, which leaves the stream's data loader unprepared: every
  process iterates its own stream (``rank`` / ``world_size``: disjoint task indices), instead of accelerate's
  ``IterableDatasetShard``, which would make each process draw every process's samples and drop all but its own.
  Batches reach the policy's device through LeRobot's pre-processor (its ``device_processor`` step).

With a :class:`~.task_pool.PoolConfig` the samples come from the rolling pool of encoded fresh tasks
(:class:`~.task_pool.TaskPool`) instead: its generator processes render and encode, the update reads encoded
frames. Its state (:class:`~.task_pool.PoolStats`: tasks received, samples, uses per task, the next task
index) is written beside every checkpoint's training state, ``training_state/task_pool.json``, by wrapping a third
name, ``save_checkpoint``; this file is written after the rest of the checkpoint, so it marks a complete save.

With an average decay (``--average.decay``) the run keeps a moving average of the trained weights
(:class:`~.weight_average.WeightAverage`), updated after every step by wrapping a fourth name,
``update_policy``, and saved with each checkpoint (``training_state/weight_average.safetensors``, before the pool's
state); a resumed run reads it back from the checkpoint it continues.

A resumed run (``--resume=true``) starts its stream or pool past every task the checkpoint could have drawn: the
pool's recorded ``next_task``, else :func:`resume_start_task`. Every process writes the stream it draws to
``OUTPUT_DIR/stream/process-R-from-task-S.json`` (the config, its rank and first task).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import torch

from ..contract import ACTION_KEY, POINTCLOUD_KEY, POINTCLOUD_NAMES, POSE_GRIPPER_NAMES, STATE_KEY
from ..pseudo_demos.stream import PseudoTaskStream, StreamConfig
from .task_pool import EncoderSource, PoolConfig, TaskPool
from .weight_average import WeightAverage, saved_decay

STREAM_REPO_ID = "local/pseudo_task_stream"
# Where each process records the stream it draws (its config, place and first task), under the run's output_dir.
STREAM_RECORDS = "stream"
# Task indices a resumed stream skips per sample the checkpoint's steps drew: room for the tasks that failed to plan
# and for the batches the data loader had prefetched.
RESUME_TASKS_PER_SAMPLE = 2
# The pool's state beside each checkpoint's training state (written last: a complete save has it).
POOL_STATE_FILE = "task_pool.json"


@dataclass
class StreamDatasetMetadata:
    """What ``lerobot-train`` reads of a dataset's ``meta``, for the stream: the data contract's features with
    ``num_points`` points per cloud, no statistics (``instant_policy`` normalises nothing outside its network), no
    cameras and no language columns. Not a ``LeRobotDatasetMetadata``: the policy reads no context bank from it."""

    num_points: int
    fps: int
    repo_id: str = STREAM_REPO_ID
    root: Path | None = None
    robot_type: str = "pseudo_task_stream"
    stats: dict | None = None
    camera_keys: tuple = ()
    has_language_columns: bool = False

    @property
    def features(self) -> dict:
        pose = {"dtype": "float32", "shape": (len(POSE_GRIPPER_NAMES),), "names": list(POSE_GRIPPER_NAMES)}
        return {
            POINTCLOUD_KEY: {"dtype": "float32", "shape": (self.num_points, 3), "names": list(POINTCLOUD_NAMES)},
            STATE_KEY: pose,
            ACTION_KEY: dict(pose),
        }


class StreamDataset(torch.utils.data.IterableDataset):
    """:class:`PseudoTaskStream` or :class:`TaskPool` as ``lerobot-train`` takes a dataset: ``meta``, and the run's
    size for its logs (``num_frames``: the samples it will draw, ``num_episodes``: the demonstrations behind them at
    one task per ``samples_per_task`` samples)."""

    def __init__(self, stream: PseudoTaskStream | TaskPool, meta: StreamDatasetMetadata, num_samples: int,
                 stream_config: StreamConfig):
        super().__init__()
        self.stream, self.meta = stream, meta
        self.num_frames = num_samples
        self.num_episodes = math.ceil(num_samples / stream_config.samples_per_task) * (stream_config.num_demos + 1)

    def __iter__(self):
        return iter(self.stream)


def resume_start_task(checkpoint_path: Path | None, batch_size: int, world_size: int) -> int:
    """The first task index of a run resumed from ``checkpoint_path`` (0 for a fresh run): past
    ``RESUME_TASKS_PER_SAMPLE`` tasks for every sample the checkpoint's steps drew on every process."""
    if checkpoint_path is None:
        return 0
    step_file = Path(checkpoint_path) / "training_state" / "training_step.json"
    step = int(json.loads(step_file.read_text())["step"])
    return step * batch_size * world_size * RESUME_TASKS_PER_SAMPLE


def pool_start_task(checkpoint_path: Path | None, batch_size: int, world_size: int) -> int:
    """The first task index of a pool run resumed from ``checkpoint_path``: the ``next_task`` its pool recorded
    (doubled past its first task when several processes ran: the record is the main process's, and the others may
    have drawn further), else :func:`resume_start_task`'s bound (a checkpoint of a stream run)."""
    if checkpoint_path is None:
        return 0
    record = Path(checkpoint_path) / "training_state" / POOL_STATE_FILE
    if not record.is_file():
        return resume_start_task(checkpoint_path, batch_size, world_size)
    state = json.loads(record.read_text())
    next_task = int(state["stats"]["next_task"])
    return next_task if world_size == 1 else 2 * next_task - int(state["start_task"])


def stream_config_for(policy_config, stream_config: StreamConfig) -> StreamConfig:
    """``stream_config`` with the N, L, T and P the policy trains on (its ``max_demos``, ``num_waypoints``,
    ``horizon`` and clouds' size), and replay priors planned as its inference plans them when it trains to refine
    (``refine_fraction`` > 0, ``replay_per_object`` / ``replay_anchored``)."""
    return dataclasses.replace(stream_config, num_demos=policy_config.max_demos,
                               num_waypoints=policy_config.num_waypoints, horizon=policy_config.horizon,
                               num_points=policy_config.num_points,
                               replay_priors=policy_config.refine_fraction > 0,
                               replay_plan=policy_config.replay_plan())


def make_stream_datasets(cfg, stream_config: StreamConfig, rank: int, world_size: int,
                         pool_config: PoolConfig | None = None):
    """``make_train_eval_datasets`` for the stream, or for the task pool with ``pool_config``: the
    :class:`StreamDataset` of this process, and no eval split. The stream renders on the policy's device when the
    data loader has no worker processes, else on the CPU in the workers; the pool renders and encodes in its own
    processes, on ``pool_config.device``."""
    config = stream_config_for(cfg.policy, stream_config)
    checkpoint = cfg.checkpoint_path if cfg.resume else None
    if pool_config is None:
        device = cfg.policy.device if cfg.num_workers == 0 else "cpu"
        start = resume_start_task(checkpoint, cfg.batch_size, world_size)
        source = PseudoTaskStream(config, device=device, rank=rank, world_size=world_size, start_task=start)
        described = source.describe()
    else:
        if cfg.num_workers != 0:
            raise ValueError("the task pool feeds the update from its own generator processes: use --num_workers=0 "
                             "and --pool.generators for more of them")
        pool_config = dataclasses.replace(pool_config, stream=config, seed=cfg.seed or 0)
        start = pool_start_task(checkpoint, cfg.batch_size, world_size)
        source = TaskPool(pool_config, policy_encoder_source(cfg.policy), rank=rank, world_size=world_size,
                          start_task=start)
        described = (f"TaskPool of {pool_config.capacity} encoded tasks fed by {pool_config.generators} generator "
                     f"process(es) on {pool_config.device}, {config.samples_per_task} live frame(s) per task; "
                     + PseudoTaskStream(config, rank=rank, world_size=world_size, start_task=start).describe())
    meta = StreamDatasetMetadata(num_points=config.num_points, fps=config.generation.fps)
    record = Path(cfg.output_dir) / STREAM_RECORDS / f"process-{rank}-from-task-{start}.json"
    record.parent.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps({"rank": rank, "world_size": world_size, "start_task": start,
                                  "config": dataclasses.asdict(config),
                                  "pool": None if pool_config is None else {
                                      key: value for key, value in dataclasses.asdict(pool_config).items()
                                      if key != "stream"}}, indent=2))
    logging.info("instant_policy: training on the pseudo-task %s from task %d (process %d of %d): %s",
                 "stream" if pool_config is None else "pool", start, rank, world_size, described)
    return StreamDataset(source, meta, cfg.steps * cfg.batch_size, config), None


def policy_encoder_source(policy_config) -> EncoderSource:
    """Where the pool's generators read the policy's frozen encoder: the checkpoint it continues
    (``pretrained_path``), else its pretrained encoder weights file."""
    if policy_config.pretrained_path is not None:
        return EncoderSource(policy_config.encoder_config, checkpoint=str(policy_config.pretrained_path))
    if not policy_config.pretrained_encoder:
        raise ValueError("the task pool needs the policy's frozen encoder to be pretrained (pretrained_encoder=true) "
                         "or a checkpoint to continue (--policy.path): a random encoder cannot be rebuilt elsewhere")
    return EncoderSource(policy_config.encoder_config, weights=str(policy_config.encoder_weights_path()))


def write_pool_state(checkpoint_dir: Path, pool: TaskPool) -> None:
    """The pool's :class:`~.task_pool.PoolStats` (and its first task) beside a checkpoint's training state."""
    pool.receive()
    state = {"start_task": pool.start_task, "stats": pool.stats().to_dict()}
    path = Path(checkpoint_dir) / "training_state" / POOL_STATE_FILE
    path.write_text(json.dumps(state, indent=2))


def stream_accelerator_class():
    """``accelerate.Accelerator`` that leaves a :class:`StreamDataset`'s data loader as it is (module docstring)."""
    from accelerate import Accelerator

    class StreamAccelerator(Accelerator):
        def prepare_data_loader(self, data_loader, device_placement=None, slice_fn_for_dispatch=None):
            if isinstance(data_loader.dataset, StreamDataset):
                return data_loader
            return super().prepare_data_loader(data_loader, device_placement, slice_fn_for_dispatch)

    return StreamAccelerator


def train(stream_config: StreamConfig, lerobot_argv: list[str], pool_config: PoolConfig | None = None,
          average_decay: float | None = None) -> None:
    """Run ``lerobot-train`` with ``lerobot_argv`` (its own flags; ``--dataset.repo_id`` and
    ``--dataset.streaming`` are set here) on ``stream_config``'s stream, or on the task pool of ``pool_config``,
    keeping a moving average of the weights with ``average_decay`` (None: none; module docstring)."""
    import sys

    for flag in ("--dataset.repo_id", "--dataset.root", "--dataset.streaming"):
        if any(arg.split("=")[0] == flag for arg in lerobot_argv):
            raise ValueError(f"{flag} is set by the stream; leave it out")
    import accelerate
    from accelerate import PartialState
    from lerobot.scripts import lerobot_train

    if average_decay is not None and not 0.0 < average_decay < 1.0:
        raise ValueError(f"--average.decay must lie in (0, 1), got {average_decay}")
    made: list[StreamDataset] = []
    resumed_from: list[Path | None] = []
    averages: list[WeightAverage] = []

    def make_datasets(cfg):  # called after lerobot-train made its Accelerator: the process's place is known
        resumed_from.append(Path(cfg.checkpoint_path) if cfg.resume else None)
        state = PartialState()
        dataset, _ = make_stream_datasets(cfg, stream_config, state.process_index, state.num_processes, pool_config)
        made.append(dataset)
        return dataset, None

    save_checkpoint, update_policy = lerobot_train.save_checkpoint, lerobot_train.update_policy

    def save_checkpoint_and_pool(checkpoint_dir, *args, **kwargs):
        save_checkpoint(checkpoint_dir, *args, **kwargs)
        if averages and averages[0] is not None:
            averages[0].save(Path(checkpoint_dir) / "training_state")
        if made and isinstance(made[0].stream, TaskPool):
            write_pool_state(checkpoint_dir, made[0].stream)

    def update_and_average(train_metrics, policy, batch, optimizer, grad_clip_norm, accelerator, *args, **kwargs):
        result = update_policy(train_metrics, policy, batch, optimizer, grad_clip_norm, accelerator, *args, **kwargs)
        model = accelerator.unwrap_model(policy)
        if not averages:  # at the first step, from the weights the run started or resumed with
            start = resumed_from[0] / "training_state" if resumed_from and resumed_from[0] is not None else None
            decay = average_decay if average_decay is not None else saved_decay(start)
            averages.append(None if decay is None else WeightAverage.resume(model, decay, start))
        if averages[0] is not None:
            averages[0].update(model)
        return result

    lerobot_train.make_train_eval_datasets = make_datasets
    lerobot_train.save_checkpoint = save_checkpoint_and_pool
    lerobot_train.update_policy = update_and_average
    accelerate.Accelerator = stream_accelerator_class()
    sys.argv = ["lerobot-train", f"--dataset.repo_id={STREAM_REPO_ID}", "--dataset.streaming=true", *lerobot_argv]
    try:
        lerobot_train.main()
    finally:
        for dataset in made:
            if isinstance(dataset.stream, TaskPool):
                dataset.stream.close()
