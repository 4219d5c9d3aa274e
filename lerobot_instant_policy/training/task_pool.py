"""A rolling pool of encoded fresh pseudo-tasks: generator processes plan, render and encode tasks; training draws
its samples from the pool without encoding anything.

The paper generated pseudo-demonstrations "continuously in parallel during training" and drew each trajectory about
57 times; what sets what the model learns is the number of *distinct tasks*, and rendering a task costs far more
than one update on it. So the unit of generation is the encoded task:

1. Each of ``generators`` processes draws its own task indices from the pseudo-task stream
   (:meth:`~..pseudo_demos.stream.PseudoTaskStream.task_indices`: the stream's seeding, disjoint from every other
   process and generator), plans each task and renders its ``N · L`` context waypoints and ``S`` live frames
   (:meth:`~..pseudo_demos.stream.PseudoTaskStream.render_tasks`), then runs the frozen geometry encoder on every
   cloud in its own EE frame (:meth:`~..model.geometry_encoder.GeometryEncoder.encode_in_frames`, the reading
   ``InstantPolicyNetwork.encode_observation`` gives). A task that cannot be planned or rendered is skipped and
   counted. The encoded task (:class:`EncodedTask`) goes into a bounded queue: a generator waits while the queue is
   full, so generation never runs ahead of the pool by more than ``queue_size`` tasks.
2. The pool (:class:`TaskPool`, in the training process) holds at most ``capacity`` tasks; a new one replaces the
   oldest. Each sample is the less used of two tasks drawn uniformly from the pool (which keeps the uses per task
   even while the pool fills), one of its ``S`` live frames drawn uniformly, with the task's context; the pool waits
   for ``min_tasks`` tasks before the first sample. Every task's uses are counted (:class:`PoolStats`).

A sample (numpy-backed tensors on the CPU, float32 unless noted), the batch layout of ``contract.ENCODED_KEYS``:
``observation.state (8,)``, ``action (T, 8)``, ``observation.scene_positions (M, 3)`` and
``observation.scene_features (M, D)`` (the live frame's scene nodes in its EE frame, in place of its cloud),
``observation.context.T_world_ee (N, L, 4, 4)``, ``observation.context.gripper_open (N, L)``,
``observation.context.scene_positions (N, L, M, 3)``, ``observation.context.scene_features (N, L, M, D)`` and
``observation.context.id`` (int64, the task index), and with the stream's replay priors ``observation.replay_prior
(T, 8)`` and ``observation.replay_prior_kept``. The policy's training forward reads it with the same graph and
loss as a batch of clouds: only the frozen encoder's work has moved.

The generators' encoder is the policy's: the frozen encoder of the checkpoint being continued, else the encoder
weights file the policy loads (:func:`frozen_encoder`). The sample draw is seeded (``seed``); which tasks are in the
pool when depends on the generators' timing, so a run is reproducible in its tasks and their contents, not in its
order.
"""

from __future__ import annotations

import dataclasses
import itertools
import multiprocessing
import os
import queue
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file

from ..contract import (
    ACTION_KEY,
    CONTEXT_GRIPPER_OPEN_KEY,
    CONTEXT_ID_KEY,
    CONTEXT_SCENE_FEATURES_KEY,
    CONTEXT_SCENE_POSITIONS_KEY,
    CONTEXT_T_WORLD_EE_KEY,
    REPLAY_PRIOR_KEPT_KEY,
    REPLAY_PRIOR_KEY,
    SCENE_FEATURES_KEY,
    SCENE_POSITIONS_KEY,
    STATE_KEY,
    poses_from_vectors,
)
from ..model.geometry_encoder import GeometryEncoder, GeometryEncoderConfig
from ..model.occupancy import load_encoder_weights
from ..pseudo_demos.stream import PseudoTaskStream, RenderedTask, StreamConfig, check_place

CHECKPOINT_ENCODER_PREFIX = "network.geometry_encoder."
_POLL_S = 0.5  # how often a waiting generator checks that its pool still wants tasks


@dataclass
class PoolConfig:
    """What :class:`TaskPool` holds and how it is fed.

    ``stream``: the tasks (:class:`~..pseudo_demos.stream.StreamConfig`; its ``samples_per_task`` is ``S``, the live
    frames rendered and encoded per task, and ``tasks_per_render`` the tasks a generator renders in one call).
    ``capacity``: tasks held, the oldest replaced (≥ ``min_tasks``). ``min_tasks``: tasks received before the first
    sample. ``generators``: generator processes; ``generator_threads``: torch threads in each. ``queue_size``: encoded
    tasks waiting between the generators and the pool. ``device``: where generators render and encode (``cpu`` or
    ``cuda``). ``seed``: the sample draw's.
    """

    stream: StreamConfig = field(default_factory=StreamConfig)
    capacity: int = 1000
    min_tasks: int = 16
    generators: int = 1
    generator_threads: int = 1
    queue_size: int = 8
    device: str = "cpu"
    seed: int = 0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """``ValueError`` naming the field for a value the pool cannot use."""
        for name in ("capacity", "min_tasks", "generators", "generator_threads", "queue_size"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"PoolConfig.{name} must be a positive integer, got {value!r}")
        if self.min_tasks > self.capacity:
            raise ValueError(f"PoolConfig.min_tasks ({self.min_tasks}) must not exceed capacity ({self.capacity})")
        if torch.device(self.device).type not in ("cpu", "cuda"):
            raise ValueError(f"PoolConfig.device must be 'cpu' or 'cuda', got {self.device!r}")
        self.stream.validate()


@dataclass
class EncodedTask:
    """One task as the pool keeps it (numpy, float32): the context's ``T_world_ee (N, L, 4, 4)``, ``gripper_open
    (N, L)``, ``scene_positions (N, L, M, 3)`` and ``scene_features (N, L, M, D)``; the ``S`` live frames' ``state
    (S, 8)``, ``actions (S, T, 8)``, ``live_positions (S, M, 3)``, ``live_features (S, M, D)`` and, when the stream
    plans them (``StreamConfig.replay_priors``), their replay priors ``replay_prior (S, T, 8)`` and whether training
    may start from them (``replay_prior_kept``)."""

    task_index: int
    T_world_ee: np.ndarray
    gripper_open: np.ndarray
    scene_positions: np.ndarray
    scene_features: np.ndarray
    state: np.ndarray
    actions: np.ndarray
    live_positions: np.ndarray
    live_features: np.ndarray
    replay_prior: np.ndarray | None = None
    replay_prior_kept: bool = True

    @property
    def num_live(self) -> int:
        return len(self.state)

    def sample(self, frame: int) -> dict[str, torch.Tensor]:
        """The training sample of live frame ``frame`` (module docstring)."""
        prior = {} if self.replay_prior is None else {REPLAY_PRIOR_KEY: torch.from_numpy(self.replay_prior[frame]),
                                                      REPLAY_PRIOR_KEPT_KEY: torch.tensor(self.replay_prior_kept)}
        return {
            STATE_KEY: torch.from_numpy(self.state[frame]),
            ACTION_KEY: torch.from_numpy(self.actions[frame]),
            SCENE_POSITIONS_KEY: torch.from_numpy(self.live_positions[frame]),
            SCENE_FEATURES_KEY: torch.from_numpy(self.live_features[frame]),
            CONTEXT_T_WORLD_EE_KEY: torch.from_numpy(self.T_world_ee),
            CONTEXT_GRIPPER_OPEN_KEY: torch.from_numpy(self.gripper_open),
            CONTEXT_SCENE_POSITIONS_KEY: torch.from_numpy(self.scene_positions),
            CONTEXT_SCENE_FEATURES_KEY: torch.from_numpy(self.scene_features),
            CONTEXT_ID_KEY: torch.tensor(self.task_index, dtype=torch.int64),
            **prior,
        }


def encode_task(task: RenderedTask, encoder: GeometryEncoder, horizon: int) -> EncodedTask:
    """A rendered task read by the frozen ``encoder``: every cloud in its own EE frame, in one call."""
    state, actions = task.live_states_and_actions(horizon)
    T_live, _ = poses_from_vectors(state)
    T_context = task.frames.T_world_ee
    T_frames = np.concatenate([T_context.reshape(-1, 4, 4), T_live])
    device = task.clouds.device
    positions, features = encoder.encode_in_frames(
        task.clouds.float(), torch.as_tensor(T_frames, dtype=torch.float32, device=device))
    positions, features = positions.cpu().numpy(), features.cpu().numpy()
    num_context = T_context.shape[0] * T_context.shape[1]
    leading = T_context.shape[:2]
    return EncodedTask(
        task_index=task.task_index,
        T_world_ee=T_context.astype(np.float32),
        gripper_open=task.frames.gripper_open.astype(np.float32),
        scene_positions=positions[:num_context].reshape(*leading, *positions.shape[1:]),
        scene_features=features[:num_context].reshape(*leading, *features.shape[1:]),
        state=state.astype(np.float32),
        actions=actions.astype(np.float32),
        live_positions=positions[num_context:],
        live_features=features[num_context:],
        replay_prior=task.replay_prior,
        replay_prior_kept=task.replay_prior_kept,
    )


def frozen_encoder(encoder_config: GeometryEncoderConfig, checkpoint: str | Path | None = None,
                   weights: str | Path | None = None) -> GeometryEncoder:
    """The frozen geometry encoder a policy trains with: the one inside ``checkpoint`` (a ``pretrained_model``
    folder whose ``model.safetensors`` holds ``network.geometry_encoder.*``), else the pretrained ``weights`` file
    (``lerobot-ip-pretrain-encoder``'s). ``ValueError`` when there is neither, or the tensors do not fit
    ``encoder_config``."""
    encoder = GeometryEncoder(encoder_config).requires_grad_(False).eval()
    if checkpoint is not None:
        path = Path(checkpoint) / "model.safetensors"
        tensors = {key[len(CHECKPOINT_ENCODER_PREFIX):]: value for key, value in load_file(str(path)).items()
                   if key.startswith(CHECKPOINT_ENCODER_PREFIX)}
        try:
            encoder.load_state_dict(tensors, strict=True)
        except RuntimeError as error:
            raise ValueError(f"the geometry encoder in {path} does not fit {encoder_config.to_dict()}: {error}") from error
    elif weights is not None:
        load_encoder_weights(encoder, weights)
    else:
        raise ValueError("the task pool encodes with the policy's frozen encoder: give a checkpoint (--policy.path) or "
                         "pretrained encoder weights (pretrained_encoder=true); a randomly initialised encoder cannot "
                         "be rebuilt in the generator processes")
    return encoder


@dataclass
class EncoderSource:
    """Where generator processes read the frozen encoder (:func:`frozen_encoder`'s arguments), picklable."""

    config: GeometryEncoderConfig
    checkpoint: str | None = None
    weights: str | None = None

    def build(self) -> GeometryEncoder:
        return frozen_encoder(self.config, self.checkpoint, self.weights)


def _generate(config: PoolConfig, source: EncoderSource, rank: int, world_size: int, start_task: int,
              generator_id: int, tasks: multiprocessing.Queue, stop: multiprocessing.Event, parent: int) -> None:
    """A generator process: encoded tasks into ``tasks`` as ``(EncodedTask, generator_id, skipped so far)`` until
    ``stop`` is set or the training process ``parent`` is gone."""
    tasks.cancel_join_thread()  # exit without flushing tasks no pool will read (its reader may be gone)
    torch.set_num_threads(config.generator_threads)
    device = torch.device(config.device)
    encoder = source.build().to(device)
    stream = PseudoTaskStream(config.stream, device=device, rank=rank, world_size=world_size, start_task=start_task)
    indices = stream.task_indices(generator_id, config.generators)
    while not stop.is_set() and os.getppid() == parent:
        for task in stream.render_tasks(list(itertools.islice(indices, config.stream.tasks_per_render))):
            item = (encode_task(task, encoder, config.stream.horizon), generator_id, stream.skipped_tasks)
            while not stop.is_set() and os.getppid() == parent:
                try:
                    tasks.put(item, timeout=_POLL_S)
                    break
                except queue.Full:
                    continue


@dataclass
class PoolStats:
    """What the pool has done since it started (``elapsed_s`` ago): ``tasks_received`` encoded tasks (``skipped``
    more could not be planned or rendered), ``samples`` drawn, ``distinct_tasks_used`` tasks drawn at least once,
    uses per used task (``mean_uses``, ``max_uses``), ``tasks_held`` now, the generation and sample rates, the
    seconds the sampler waited for tasks (``waited_s``), and ``next_task``: a task index past every task received
    (where a continuing run's generators start)."""

    elapsed_s: float
    tasks_received: int
    skipped: int
    samples: int
    distinct_tasks_used: int
    mean_uses: float
    max_uses: int
    tasks_held: int
    fresh_tasks_per_s: float
    samples_per_s: float
    waited_s: float
    next_task: int

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class TaskPool(torch.utils.data.IterableDataset):
    """The rolling pool (module docstring): an endless iterable of samples, iterated in the training process
    (``DataLoader(num_workers=0)``: the pool itself spreads generation over processes).

    Args:
        config: :class:`PoolConfig`.
        encoder: where the generators read the frozen encoder (:class:`EncoderSource`).
        rank, world_size: this training process among ``world_size``: its task indices are its own.
        start_task: the first task index (``PoolStats.next_task`` of the run this one continues).
    """

    def __init__(self, config: PoolConfig, encoder: EncoderSource, rank: int = 0, world_size: int = 1,
                 start_task: int = 0):
        super().__init__()
        config.validate()
        check_place(rank, world_size, start_task)
        self.config, self.encoder = config, encoder
        self.rank, self.world_size, self.start_task = rank, world_size, start_task
        self._tasks: deque[EncodedTask] = deque()
        self._uses: dict[int, int] = {}
        self._skipped = [0] * config.generators
        self._max_index = start_task - 1
        self._samples = 0
        self._waited_s = 0.0
        self._started_at: float | None = None
        self._rng = np.random.default_rng([config.seed, rank])
        self._context = multiprocessing.get_context("spawn")
        self._queue = None
        self._stop = None
        self._processes: list = []

    # ------------------------------------------------------------------ generators
    def start(self) -> None:
        """Start the generator processes (the first iteration does it)."""
        if self._processes:
            return
        self._queue = self._context.Queue(maxsize=self.config.queue_size)
        self._stop = self._context.Event()
        for generator_id in range(self.config.generators):
            process = self._context.Process(
                target=_generate, daemon=True, name=f"task-pool-generator-{generator_id}",
                args=(self.config, self.encoder, self.rank, self.world_size, self.start_task, generator_id,
                      self._queue, self._stop, os.getpid()))
            process.start()
            self._processes.append(process)
        self._started_at = time.monotonic()

    def close(self) -> None:
        """Stop the generators and wait for them (a second call does nothing)."""
        if not self._processes:
            return
        self._stop.set()
        while True:  # a generator blocked in put() exits only once the queue has room
            try:
                self._queue.get_nowait()
            except queue.Empty:
                break
        for process in self._processes:
            process.join(timeout=10)
            if process.is_alive():
                process.terminate()
                process.join()
        self._processes = []

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown: the daemonic generators die with the process
            pass

    # ------------------------------------------------------------------ the pool
    def receive(self, block: bool = False) -> int:
        """Move the encoded tasks waiting in the queue into the pool (replacing the oldest beyond ``capacity``);
        with ``block``, wait for at least one. Returns the number received. ``RuntimeError`` when a generator died."""
        self.start()
        received = 0
        while True:
            try:
                task, generator_id, skipped = self._queue.get(timeout=_POLL_S) if block and not received \
                    else self._queue.get_nowait()
            except queue.Empty:
                if block and not received:
                    self._check_generators()
                    continue
                return received
            self._tasks.append(task)
            self._uses.setdefault(task.task_index, 0)
            self._skipped[generator_id] = skipped
            self._max_index = max(self._max_index, task.task_index)
            received += 1
            if len(self._tasks) > self.config.capacity:
                self._tasks.popleft()

    def _check_generators(self) -> None:
        dead = [process for process in self._processes if not process.is_alive()]
        if dead:
            codes = ", ".join(f"{process.name} exit code {process.exitcode}" for process in dead)
            raise RuntimeError(f"task pool generator process(es) stopped: {codes}")

    def draw(self) -> dict[str, torch.Tensor]:
        """One sample: the pool first takes in what the generators made (waiting until it holds ``min_tasks``)."""
        self.receive()
        if len(self._tasks) < self.config.min_tasks:
            started = time.monotonic()
            while len(self._tasks) < self.config.min_tasks:
                self.receive(block=True)
            self._waited_s += time.monotonic() - started
        # The less used of two tasks drawn uniformly ("two choices"): uses stay even across tasks, also while the
        # pool fills, without drawing one fresh task into a whole batch.
        first, second = (self._tasks[int(index)] for index in self._rng.integers(len(self._tasks), size=2))
        task = first if self._uses[first.task_index] <= self._uses[second.task_index] else second
        self._uses[task.task_index] += 1
        self._samples += 1
        return task.sample(int(self._rng.integers(task.num_live)))

    def __iter__(self):
        if torch.utils.data.get_worker_info() is not None:
            raise RuntimeError("iterate the task pool in the training process (DataLoader num_workers=0): its "
                               "generators are processes of their own (PoolConfig.generators)")
        while True:
            yield self.draw()

    def stats(self) -> PoolStats:
        elapsed = time.monotonic() - self._started_at if self._started_at is not None else 0.0
        used = [uses for uses in self._uses.values() if uses > 0]
        stride = self.world_size * self.config.generators
        # Every generator's next index lies past the largest received, rounded up to a whole round of indices.
        rounds = (self._max_index - self.start_task) // stride + 1
        return PoolStats(
            elapsed_s=elapsed, tasks_received=len(self._uses), skipped=sum(self._skipped), samples=self._samples,
            distinct_tasks_used=len(used), mean_uses=float(np.mean(used)) if used else 0.0,
            max_uses=max(used, default=0), tasks_held=len(self._tasks),
            fresh_tasks_per_s=len(self._uses) / elapsed if elapsed else 0.0,
            samples_per_s=self._samples / elapsed if elapsed else 0.0, waited_s=self._waited_s,
            next_task=self.start_task + max(rounds, 0) * stride,
        )


__all__ = ["EncodedTask", "EncoderSource", "PoolConfig", "PoolStats", "TaskPool", "encode_task", "frozen_encoder"]
