"""A never-repeating stream of pseudo-task training samples, rendered by z-buffer splatting.

Task ``i`` is planned by :func:`~.generation.plan_task`, the code ``lerobot-ip-generate`` writes its datasets with,
from the random stream ``(seed, i)`` of the generation config: its objects, its waypoints and ``N + 1``
demonstrations (layouts, disturbances, gripper faults, tracked object poses), of which the first ``N`` are the
context and the last is the live one. For the same config and task index the stream and a generated dataset
therefore hold the same demonstrations; only the renderer differs (``lerobot-ip-generate --renderer splat`` splats
every frame of them as this stream does). Only the frames a sample needs are rendered:
each context demonstration's ``L`` waypoints (:func:`~..data.context_bank.waypoint_frames`, as the context bank
reduces a dataset's episodes) and ``samples_per_task`` live frames drawn uniformly from the stream
``(seed, i, 4)``. The visible surface samples of ``tasks_per_render`` tasks come from one
:class:`~..objects.splatting.SplatRenderer` call on ``device``, with the generation config's cameras and the gripper
occluding (never in the cloud). Each cloud is then reduced to ``P`` points by farthest-point sampling, as the dataset
path reduces pybullet's clouds, in one of two ways (``StreamConfig.resampling``): ``"fpsample"``, the dataset
path's own :func:`~..geometry.sampling.resample_indices` (bucket FPS on the host, its start and repeats drawn from
the stream ``(seed, i, 5)``), about 10 ms a cloud on one CPU core; or ``"masked_fps"``, the renderer's exact FPS
of the whole batch on ``device`` (:func:`~..geometry.masked_fps.masked_farthest_point_sampling`, its start drawn
from the config's seed), which costs the CPU ten times more but keeps an accelerator's batch on the accelerator.
``"auto"`` (the default) takes the first on the CPU and the second elsewhere. Either way a cloud depends only on
its task, never on the tasks rendered beside it.

Each process and DataLoader worker draws its own task indices, ``start_task + k · world_size · workers + rank ·
workers + worker`` for ``k = 0, 1, …``: disjoint from every other, the same for a seed. A task that cannot be
planned (no scene fits), whose context demonstrations are shorter than ``L`` frames, or one of whose clouds comes
out empty is skipped and counted (:attr:`PseudoTaskStream.skipped_tasks`).

A sample (a dict of tensors on ``device``, float32 unless noted), for a live frame ``t``:

- ``observation.pointcloud (P, 3)``: the live demonstration's cloud at ``t``, world frame;
- ``observation.state (8,)``: its EE state at ``t`` (xyz, quaternion xyzw, gripper_open, as a dataset's);
- ``action (T, 8)``: its actions ``t … t + T − 1``, the last one held past its end;
- ``observation.context.pointcloud (N, L, P, 3)``, ``observation.context.T_world_ee (N, L, 4, 4)``,
  ``observation.context.gripper_open (N, L)``: the context demonstrations' waypoints, world frame;
- ``observation.context.id`` (int64 scalar): the task index; rows with one id share their context;
- with ``StreamConfig.replay_priors``, ``observation.replay_prior (T, 8)``: the replay prior of actions
  ``t … t + T − 1`` (:func:`~..replay.priors.replay_prior_actions`: the plan's actions from the plan step the live
  demonstration has reached at ``t``), world frame, and ``observation.replay_prior_kept`` (bool): False for a task
  whose plan is wrong against its live demonstration and is not among the wrong ones kept
  (``StreamConfig.wrong_prior_keep``, drawn per task from the stream ``(seed, i, 6)``); with
  ``StreamConfig.prior_time_shift`` each frame's prior read up to that many plan steps early or late (drawn per
  frame, uniformly, from ``(seed, i, 7)``).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..config_io import load_config
from ..contract import (
    ACTION_KEY,
    CONTEXT_GRIPPER_OPEN_KEY,
    CONTEXT_ID_KEY,
    CONTEXT_POINTCLOUD_KEY,
    CONTEXT_T_WORLD_EE_KEY,
    NUM_POINTS,
    POINTCLOUD_KEY,
    REPLAY_PRIOR_KEPT_KEY,
    REPLAY_PRIOR_KEY,
    STATE_KEY,
)
from ..data.context_bank import waypoint_frames
from ..data.demonstrations import DemonstrationError
from ..objects.splatting import DEFAULT_SURFACE_SAMPLES, SplatConfig, SplatRenderer, resample_visible
from ..replay.plan import REPLAY_PLANS, ReplaySource
from ..replay.priors import replay_prior_actions
from .generation import GenerationConfig, PlannedTask, plan_task
from .replay import GenerationError, splat_inputs

_LIVE_STREAM = 4  # the live frames of task i are drawn from the random stream (seed, i, 4)
_RESAMPLE_STREAM = 5  # and its clouds resampled ("fpsample") from (seed, i, 5)
_PRIOR_STREAM = 6  # and whether its wrong replay prior is kept from (seed, i, 6)
_PRIOR_TIMING_STREAM = 7  # and its replay priors' timing errors from (seed, i, 7)
RESAMPLINGS = ("auto", "fpsample", "masked_fps")


@dataclass
class StreamConfig:
    """What :class:`PseudoTaskStream` draws.

    ``generation``: the distributions (family, object split or pool, biased fraction, demonstration layout and
    augmentation, waypoint roll, tasks per object group, seed, cameras), read as ``lerobot-ip-generate`` reads them;
    its ``demos_per_task`` is not used (each task plans ``num_demos + 1``), nor are its output settings.
    ``num_demos`` N context demonstrations per task; ``num_waypoints`` L per context demonstration; ``horizon`` T
    actions per sample; ``num_points`` P per cloud; ``samples_per_task`` live frames drawn per task (1: every sample
    from a task never drawn before; more where rendering is dear); ``tasks_per_render`` tasks planned, then
    rendered in one splatting call (memory grows with it: a few hundred bytes per surface sample, camera and
    cloud). Splatting: ``surface_samples`` per object, ``zbuffer_resolution`` ``(w, h)``, ``splat_radius`` (pixels)
    and ``depth_tolerance`` (m), as :class:`~..objects.splatting.SplatConfig`; ``resampling`` one of
    ``RESAMPLINGS`` (see the module docstring). ``replay_priors``: each sample also carries the live frame's replay
    prior (:func:`~..replay.priors.replay_prior_actions`, the live demonstration's first cloud rendered for it, one
    cloud more per task), planned as ``replay_plan`` names (one of :data:`~..replay.plan.REPLAY_PLANS`);
    ``wrong_prior_keep``: the probability that a task whose plan is wrong keeps its prior for training (1: all kept;
    below 1 brings the share of wrong priors down towards the share of wrong replays a policy meets, module
    docstring);
    ``prior_time_shift``: the largest timing error of a prior, in plan steps (each live frame's prior is read that
    many steps early or late at most, :mod:`~..replay.timing`; 0: on time).
    """

    generation: GenerationConfig = field(default_factory=GenerationConfig)
    num_demos: int = 2
    num_waypoints: int = 10
    horizon: int = 8
    num_points: int = NUM_POINTS
    samples_per_task: int = 1
    tasks_per_render: int = 4
    surface_samples: int = DEFAULT_SURFACE_SAMPLES
    zbuffer_resolution: tuple[int, int] = (480, 360)
    splat_radius: int = 1
    depth_tolerance: float = 0.006
    resampling: str = "auto"
    replay_priors: bool = False
    replay_plan: str = "per_object"
    wrong_prior_keep: float = 1.0
    prior_time_shift: int = 0

    def __post_init__(self) -> None:
        self.validate()

    @classmethod
    def from_generate_config(cls, path: str | Path, **overrides) -> StreamConfig:
        """The stream of the distributions in a ``lerobot-ip-generate`` config file (``configs/generate/*.json``);
        ``overrides`` set the stream's own fields."""
        return cls(generation=load_config(GenerationConfig, path), **overrides)

    def validate(self) -> None:
        """``ValueError`` naming the field for a value the stream cannot use."""
        for name in ("num_demos", "horizon", "num_points", "samples_per_task", "tasks_per_render", "surface_samples"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"StreamConfig.{name} must be a positive integer, got {value!r}")
        if not isinstance(self.num_waypoints, int) or isinstance(self.num_waypoints, bool) or self.num_waypoints < 2:
            raise ValueError(f"StreamConfig.num_waypoints must be an integer ≥ 2, got {self.num_waypoints!r}")
        shift = self.prior_time_shift
        if not isinstance(shift, int) or isinstance(shift, bool) or shift < 0:
            raise ValueError(f"StreamConfig.prior_time_shift must be a non-negative integer, got {shift!r}")
        if not 0.0 <= self.wrong_prior_keep <= 1.0:
            raise ValueError(f"StreamConfig.wrong_prior_keep must lie in [0, 1], got {self.wrong_prior_keep!r}")
        if self.replay_plan not in REPLAY_PLANS:
            raise ValueError(f"StreamConfig.replay_plan must be one of {list(REPLAY_PLANS)}, got {self.replay_plan!r}")
        if self.resampling not in RESAMPLINGS:
            raise ValueError(f"StreamConfig.resampling must be one of {list(RESAMPLINGS)}, got {self.resampling!r}")
        if not isinstance(self.generation, GenerationConfig):
            raise ValueError(
                f"StreamConfig.generation must be a GenerationConfig, got {type(self.generation).__name__}"
            )
        self.generation.validate()
        if self.generation.render.cloud != "cameras":
            raise ValueError(
                f"StreamConfig.generation.render.cloud must be 'cameras' (the stream renders the cameras' partial "
                f"views), got {self.generation.render.cloud!r}"
            )
        try:
            self.splat_config()
        except (TypeError, ValueError) as error:
            raise ValueError(f"StreamConfig splat settings: {error}") from error

    def splat_config(self) -> SplatConfig:
        """The renderer's settings: the generation config's cameras and gripper, this config's splatting sizes."""
        return SplatConfig(
            cameras=self.generation.render.cameras,
            zbuffer_resolution=tuple(self.zbuffer_resolution),
            splat_radius=self.splat_radius,
            depth_tolerance=self.depth_tolerance,
            gripper_occludes=self.generation.render.gripper_occludes,
        )


@dataclass
class _TaskFrames:
    """The frames one planned task renders: per context demonstration its waypoints (``chosen (N, L)`` frame
    indices, ``T_world_ee (N, L, 4, 4)``, ``gripper_open (N, L)``) and the live frames ``live (S,)``."""

    planned: PlannedTask
    chosen: np.ndarray
    T_world_ee: np.ndarray
    gripper_open: np.ndarray
    live: np.ndarray


def check_place(rank: int, world_size: int, start_task: int) -> None:
    """``ValueError`` naming a process place (``rank`` of ``world_size``) or a first task index that cannot be used."""
    if not isinstance(world_size, int) or world_size < 1:
        raise ValueError(f"world_size must be a positive integer, got {world_size!r}")
    if not isinstance(rank, int) or not 0 <= rank < world_size:
        raise ValueError(f"rank must be an integer in [0, world_size = {world_size}), got {rank!r}")
    if not isinstance(start_task, int) or start_task < 0:
        raise ValueError(f"start_task must be a non-negative integer, got {start_task!r}")


@dataclass
class RenderedTask:
    """One planned task's rendered frames: ``clouds (N·L + S, P, 3)`` world frame, on the stream's device, its ``N · L``
    context waypoints (demonstration-major) then its ``S`` live frames; with ``StreamConfig.replay_priors`` the live
    frames' replay priors ``replay_prior (S, T, 8)`` (:mod:`~..replay.priors`), else None, and whether training may
    start from them (``replay_prior_kept``, module docstring)."""

    frames: _TaskFrames
    clouds: torch.Tensor
    replay_prior: np.ndarray | None = None
    replay_prior_kept: bool = True

    @property
    def task_index(self) -> int:
        return self.frames.planned.task_index

    @property
    def context_clouds(self) -> torch.Tensor:
        """``(N, L, P, 3)`` the context waypoints' clouds."""
        num_demos, num_waypoints = self.frames.chosen.shape
        return self.clouds[: num_demos * num_waypoints].reshape(num_demos, num_waypoints, *self.clouds.shape[1:])

    @property
    def live_clouds(self) -> torch.Tensor:
        """``(S, P, 3)`` the live frames' clouds."""
        return self.clouds[self.frames.chosen.size:]

    def live_states_and_actions(self, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """The live frames' EE states ``(S, 8)`` and their next ``horizon`` actions ``(S, T, 8)``, the live
        demonstration's last action held past its end."""
        live = self.frames.planned.demos[-1]
        steps = np.minimum(self.frames.live[:, None] + np.arange(horizon), live.num_frames - 1)
        return live.state[self.frames.live], live.action[steps]


class PseudoTaskStream(torch.utils.data.IterableDataset):
    """An endless stream of training samples from fresh pseudo-tasks (see the module docstring).

    Args:
        config: what to draw (:class:`StreamConfig`).
        device: where the clouds are rendered and every sample's tensors live.
        rank, world_size: this process among ``world_size`` (several GPUs): its task indices are its own.
        start_task: the first task index of the stream (e.g. past the tasks an earlier run drew).
    """

    def __init__(
        self,
        config: StreamConfig,
        device: torch.device | str = "cpu",
        rank: int = 0,
        world_size: int = 1,
        start_task: int = 0,
    ):
        super().__init__()
        config.validate()
        check_place(rank, world_size, start_task)
        self.config = config
        self.device = torch.device(device)
        self.rank, self.world_size, self.start_task = rank, world_size, start_task
        self.skipped_tasks = 0
        self.resampling = config.resampling
        if self.resampling == "auto":
            self.resampling = "fpsample" if self.device.type == "cpu" else "masked_fps"
        self._renderer: SplatRenderer | None = None

    def task_indices(self, worker_id: int = 0, num_workers: int = 1) -> Iterator[int]:
        """The endless task indices of this process's DataLoader worker ``worker_id`` of ``num_workers``."""
        stride = self.world_size * num_workers
        return itertools.count(self.start_task + self.rank * num_workers + worker_id, stride)

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        info = torch.utils.data.get_worker_info()
        indices = self.task_indices(info.id, info.num_workers) if info is not None else self.task_indices()
        while True:
            yield from self._samples(list(itertools.islice(indices, self.config.tasks_per_render)))

    def describe(self) -> str:
        """What the stream draws, in one paragraph."""
        config, generation = self.config, self.config.generation
        objects = (
            f"objects from a pool of {len(generation.pool())}" if generation.object_pool is not None
            else f"objects of the {generation.object_split!r} split"
        )
        width, height = config.zbuffer_resolution
        return (
            f"PseudoTaskStream: fresh {generation.family!r} pseudo-tasks (seed {generation.seed}, {objects}, "
            f"biased fraction {generation.biased_fraction}, {generation.tasks_per_object_group} task(s) per object "
            f"group, one-layout fraction {generation.demo.shared_layout_fraction}, layout shift "
            f"{generation.demo.layout_shift}); rank {self.rank} of {self.world_size} from task {self.start_task}. "
            f"Per task N={config.num_demos} context demonstrations × L={config.num_waypoints} waypoints and "
            f"{config.samples_per_task} live frame(s) with T={config.horizon} actions; clouds of P={config.num_points} "
            f"points from {len(generation.render.cameras)} cameras, splatted from {config.surface_samples} samples per "
            f"object into {width}×{height} z-buffers on {self.device}, {config.tasks_per_render} task(s) per render, "
            f"resampled by {self.resampling}; "
            f"{self.skipped_tasks} task(s) skipped so far."
        )

    def __repr__(self) -> str:
        return self.describe()

    def _samples(self, task_indices: list[int]) -> list[dict[str, torch.Tensor]]:
        """Plan the tasks ``task_indices``, render all their clouds in one call, and return their samples in order
        (``samples_per_task`` per task that is not skipped)."""
        samples = []
        for task in self.render_tasks(task_indices):
            samples.extend(self._task_samples(task))
        return samples

    def render_tasks(self, task_indices: list[int]) -> list[RenderedTask]:
        """Plan the tasks ``task_indices`` and render all their clouds in one call: one :class:`RenderedTask` per
        task that is not skipped, in order (the skipped ones counted in :attr:`skipped_tasks`)."""
        tasks = [frames for frames in map(self._plan, task_indices) if frames is not None]
        rendered = []
        for frames, clouds in zip(tasks, self._render(tasks) if tasks else []):
            if clouds is None:
                self.skipped_tasks += 1
            elif self.config.replay_priors:
                rendered.append(self._with_replay_prior(frames, clouds))
            else:
                rendered.append(RenderedTask(frames, clouds))
        return rendered

    def _with_replay_prior(self, frames: _TaskFrames, clouds: torch.Tensor) -> RenderedTask:
        """The rendered task of ``clouds`` (its frames, then the live demonstration's first cloud) with its replay
        prior, planned from the first context demonstration's first waypoint cloud (every demonstration's frame 0 is
        its first waypoint) onto that first cloud, each frame's read off by up to ``prior_time_shift`` plan steps; a
        wrong one kept with probability ``wrong_prior_keep``."""
        task = RenderedTask(frames, clouds[:-1])
        context_first = task.context_clouds[0, 0].cpu().numpy()
        shift, shifts = self.config.prior_time_shift, None
        if shift:
            timing = np.random.default_rng([self.config.generation.seed, task.task_index, _PRIOR_TIMING_STREAM])
            shifts = timing.integers(-shift, shift + 1, size=len(frames.live))
        first, live = frames.planned.demos[0], frames.planned.demos[-1]
        prior = replay_prior_actions(ReplaySource(context_first, first.action), clouds[-1].cpu().numpy(), live.state,
                                     live.action, frames.live, self.config.horizon, self.config.replay_plan, shifts)
        task.replay_prior = prior.actions
        if prior.wrong:
            draw = np.random.default_rng([self.config.generation.seed, task.task_index, _PRIOR_STREAM]).random()
            task.replay_prior_kept = bool(draw < self.config.wrong_prior_keep)
        return task

    def _plan(self, task_index: int) -> _TaskFrames | None:
        """Task ``task_index`` planned with ``N + 1`` demonstrations and the frames to render; None (counted as
        skipped) when it cannot be planned or a context demonstration is shorter than ``L`` frames."""
        config = self.config
        try:
            planned = plan_task(config.generation, task_index, config.num_demos + 1)
            waypoints = [
                waypoint_frames(demo.state, demo.action, config.num_waypoints)
                for demo in planned.demos[: config.num_demos]
            ]
        except (GenerationError, DemonstrationError):
            self.skipped_tasks += 1
            return None
        chosen, T_world_ee, gripper_open = (np.stack(arrays) for arrays in zip(*waypoints))
        rng = np.random.default_rng([config.generation.seed, task_index, _LIVE_STREAM])
        live = rng.integers(0, planned.demos[-1].num_frames, size=config.samples_per_task)
        return _TaskFrames(planned, chosen, T_world_ee, gripper_open, live)

    def _render(self, tasks: list[_TaskFrames]) -> list[torch.Tensor | None]:
        """Every cloud of ``tasks`` from one :class:`SplatRenderer` call: per task ``(N·L + S, P, 3)`` on
        ``device``, its ``N · L`` context waypoints (demonstration-major) then its ``S`` live frames (and, with
        ``replay_priors``, the live demonstration's first frame), or None when one of them shows no object point."""
        if self._renderer is None:
            self._renderer = SplatRenderer(self.config.splat_config(), self.device)
        per_task = []
        for frames in tasks:
            demos = frames.planned.demos
            scenes = [(demo, frame) for demo, row in zip(demos, frames.chosen) for frame in row]
            scenes += [(demos[-1], frame) for frame in frames.live]
            if self.config.replay_priors:
                scenes.append((demos[-1], 0))
            per_task.append(splat_inputs(frames.planned.objects, scenes, self.config.surface_samples))
        inputs = {key: torch.cat([task_inputs[key] for task_inputs in per_task]) for key in per_task[0]}
        bounds = np.cumsum([0, *(len(task_inputs["T_world_ee"]) for task_inputs in per_task)])
        if self.resampling == "masked_fps":
            cloud = self._renderer.render(**inputs, num_points=self.config.num_points, seed=self.config.generation.seed)
            return [
                None if bool((cloud.num_visible[start:stop] == 0).any()) else cloud.points_world[start:stop]
                for start, stop in zip(bounds[:-1], bounds[1:])
            ]
        posed, visible = self._renderer.visible(**inputs)
        posed, visible = posed.cpu().numpy(), visible.cpu().numpy()
        clouds = []
        for frames, start, stop in zip(tasks, bounds[:-1], bounds[1:]):
            if not visible[start:stop].any(axis=1).all():
                clouds.append(None)
                continue
            rng = np.random.default_rng([self.config.generation.seed, frames.planned.task_index, _RESAMPLE_STREAM])
            chosen = resample_visible(visible[start:stop], posed[start:stop], self.config.num_points, rng)
            clouds.append(torch.as_tensor(np.take_along_axis(posed[start:stop], chosen[..., None], axis=1),
                                          device=self.device))
        return clouds

    def _task_samples(self, task: RenderedTask) -> list[dict[str, torch.Tensor]]:
        """The samples of one rendered task."""
        device = self.device
        context = {
            CONTEXT_POINTCLOUD_KEY: task.context_clouds,
            CONTEXT_T_WORLD_EE_KEY: torch.as_tensor(task.frames.T_world_ee, device=device),
            CONTEXT_GRIPPER_OPEN_KEY: torch.as_tensor(task.frames.gripper_open, device=device),
            CONTEXT_ID_KEY: torch.tensor(task.task_index, dtype=torch.int64, device=device),
        }
        state, actions = task.live_states_and_actions(self.config.horizon)
        samples = [{POINTCLOUD_KEY: cloud, STATE_KEY: torch.as_tensor(state[index], device=device),
                    ACTION_KEY: torch.as_tensor(actions[index], device=device), **context}
                   for index, cloud in enumerate(task.live_clouds)]
        if task.replay_prior is not None:
            for sample, prior in zip(samples, task.replay_prior, strict=True):
                sample[REPLAY_PRIOR_KEY] = torch.as_tensor(prior, device=device)
                sample[REPLAY_PRIOR_KEPT_KEY] = torch.tensor(task.replay_prior_kept, device=device)
        return samples


__all__ = ["PseudoTaskStream", "RenderedTask", "StreamConfig", "check_place"]
