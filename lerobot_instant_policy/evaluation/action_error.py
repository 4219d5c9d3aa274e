"""Offline action error of an ``instant_policy`` checkpoint on held-out pseudo-tasks (``lerobot-ip-action-error``), at
one setting of the inference parameters K (denoising steps), N (context demonstrations) and L (waypoints per
demonstration), measured without a simulator, against holding still and the context swap.

For each of the first ``tasks`` pseudo-tasks of a pseudo-demonstration dataset (written by ``lerobot-ip-generate``,
episodes of one pseudo-task share its ``task`` string), in order of their first episode:

* its **last** episode is the "live" episode, its **first N** episodes the context demonstrations (so N must be at
  most demos-per-task − 1: the live episode is never its own context);
* ``frames_per_task`` frames t of the live episode are drawn without replacement (``numpy`` RNG seeded with
  ``seed``, per task); at each frame the policy sees the live cloud ``points_world[t] (P, 3)`` and state
  ``state[t] (8,)`` (world frame) and predicts a chunk ``(T, 8)`` of absolute world-frame EE targets;
* the ground truth is the live episode's ``action[t … t+T−1] (T, 8)``, held at its last action past the end;
* the DDIM noise of every frame comes from a ``torch.Generator`` seeded from (``seed``, task, frame) only, so all
  settings are compared on the same noise.

Errors, averaged over all frames and all T horizon steps: translation ``‖p̂ − p‖`` in millimetres (world frame),
rotation the geodesic angle between the predicted and true EE orientations in degrees, gripper accuracy the fraction
of steps whose open/closed command (threshold 0.5) is right, at the setting asked (default K=4, N=2, L=10; each in
the range the config accepts, :mod:`..model.bounds`, judged by the config's own checks). Three references at that
setting: the same config freshly initialised (``torch.manual_seed(0)``; its frozen geometry encoder is the config's
pretrained one, as in a checkpoint before training), "hold": predicting the current state for every horizon step (no
model), and the **context swap**: the same checkpoint, frames and noise, with the demonstrations of the *next*
pseudo-task (in the order above, the last task taking the first's) relabelled as this task's. **Context gain** = swap
error / own error, for translation, rotation and gripper (error = 1 − accuracy): about 1 for a policy that ignores
its demonstrations. The setting's translation error, holding still's and the swap's are also given per third of the
live episodes (``phases``: the approach, the middle, the end), to show where along a task the demonstrations are read,
and per pseudo-task (``per_task``: its frames and its mean translation errors, own, holding still's and the swap's).

Intervals. The frames of one task share its difficulty, so they are not independent draws: the two figures a reader
compares, the translation error over holding still's (own / hold, "× holding still") and the context gain in
translation (swap / own), carry a 95% percentile cluster bootstrap interval over tasks (``intervals``): the tasks are
resampled with replacement (10,000 resamples from a ``numpy`` generator with a fixed seed, so the same per-task errors
give the same interval), each ratio of mean errors is recomputed on the resample's frames, and the interval is the
2.5th and 97.5th percentiles (none for a single task). Two results on the same frames (two checkpoints, say) compare
paired with :func:`paired_ratio_difference`: the difference of each ratio, with the tasks resampled jointly for both.

K is handed to ``predict_action_chunk`` (``num_inference_steps``) at every prediction; the checkpoint's config is
left as it was loaded, except ``samples_per_prediction`` when given (every setting and reference then predicts the
mean of that many samples, drawn from the frame's generator). The repository's sweep of several settings (the
paper's table 2, right half) is ``python -m workbench.cli.action_error_sweep``, built on :func:`open_probe`,
:func:`evaluate_setting` and :func:`references`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
import time
from itertools import zip_longest
from pathlib import Path

import numpy as np
import torch

from ..contract import POINTCLOUD_KEY, STATE_KEY
from ..data.demonstrations import Demonstration, episodes_by_task, open_demo_dataset, read_demonstration
from ..modeling_instant_policy import InstantPolicyPolicy
from ..replay.plan import ReplayPlan
from ..replay.priors import plan_onto_live, replay_priors
from ..replay.segments import plan_is_wrong
from ..replay.timing import plan_steps
from .bootstrap import CONFIDENCE, cluster_bootstrap
from .checkpoints import Checkpoint, checkpoint_config, load_policy
from .loss_curve import check_pseudo_demo_root
from .replay_error import THIRDS, third_of

DEFAULT_K, DEFAULT_N, DEFAULT_L = 4, 2, 10
RATIOS = ("vs_holding_still", "context_gain_translation")  # own / hold and swap / own, of the translation error
BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED = 10_000, 0
PAIRED_KEYS = ("seed", "frames_per_task", "horizon_T", "per_task")  # what paired_ratio_difference reads of a result
HOLD_TOLERANCE_MM = 0.01  # holding still's error on a task further apart than this: other frames, not paired


class ActionErrorError(ValueError):
    """Bad settings (N too large for the dataset, K, N, L or S outside the supported range, …)."""


@dataclasses.dataclass
class LiveFrame:
    """One evaluated frame: ``points (P, 3)`` and ``state (8,)`` of the live episode at frame ``t`` (world frame),
    ``target (T, 8)`` its actions t … t+T−1 (held at the last one), ``noise_seed`` of its DDIM generator, and
    ``phase``, the third of the live episode that ``t`` lies in (0, 1, 2: :data:`THIRDS`)."""

    t: int
    points: np.ndarray
    state: np.ndarray
    target: np.ndarray
    noise_seed: int
    phase: int


@dataclasses.dataclass
class HeldOutTask:
    """A pseudo-task: its ``demos`` (all episodes but the last, in episode order), the last episode ``live`` and
    ``frames`` of it; the live episode's first cloud places a replay (:meth:`replay_plan`), its states time it."""

    task: str
    live_episode: int
    demos: list[Demonstration]
    frames: list[LiveFrame]
    live: Demonstration
    _plans: dict = dataclasses.field(default_factory=dict, repr=False)
    _priors: dict = dataclasses.field(default_factory=dict, repr=False)

    def replay_plan(self, num_demos: int, plan: str) -> ReplayPlan:
        """The ``plan`` replay of the first ``num_demos`` demonstrations onto the live episode's first cloud
        (:func:`~..replay.priors.plan_onto_live`), planned once per setting."""
        key = (num_demos, plan)
        if key not in self._plans:
            self._plans[key] = plan_onto_live(self.task, self.demos[:num_demos], self.live.points_world[0], plan)
        return self._plans[key]

    def replay_priors(self, num_demos: int, horizon: int, plan: str) -> np.ndarray:
        """``(frames, T, 8)``: the replay prior of every frame from :meth:`replay_plan`, read at the plan step the
        live episode has reached there (:func:`~..replay.timing.plan_steps` on its states,
        :func:`~..replay.priors.replay_priors`), computed once per setting."""
        key = (num_demos, horizon, plan)
        if key not in self._priors:
            planned = self.replay_plan(num_demos, plan)
            steps = plan_steps(self.live.state, planned.actions)[[frame.t for frame in self.frames]]
            self._priors[key] = replay_priors(planned, steps, horizon)
        return self._priors[key]

    def replay_is_wrong(self, num_demos: int, plan: str) -> bool:
        """Whether :meth:`replay_plan` is wrong against the live episode (:func:`~..replay.segments.
        plan_is_wrong`)."""
        return plan_is_wrong(self.replay_plan(num_demos, plan).actions, self.live.action)


# ---------------------------------------------------------------------------------------------------- errors
def chunk_errors(predicted: np.ndarray, target: np.ndarray) -> dict[str, np.ndarray]:
    """Per-step errors of ``predicted`` vs ``target``, both ``(..., 8)`` (xyz m, quaternion xyzw, gripper):
    ``translation_mm (...)``, ``rotation_deg (...)`` (geodesic angle, sign of the quaternion ignored),
    ``gripper_correct (...)`` (bool, commands thresholded at 0.5)."""
    if predicted.shape != target.shape or predicted.shape[-1] != 8:
        raise ValueError(f"predicted and target must both have shape (..., 8), got {predicted.shape}, {target.shape}")
    translation = 1000.0 * np.linalg.norm(predicted[..., :3] - target[..., :3], axis=-1)
    q_pred = predicted[..., 3:7] / np.linalg.norm(predicted[..., 3:7], axis=-1, keepdims=True)
    q_true = target[..., 3:7] / np.linalg.norm(target[..., 3:7], axis=-1, keepdims=True)
    dot = np.clip(np.abs(np.sum(q_pred * q_true, axis=-1)), 0.0, 1.0)
    rotation = np.degrees(2.0 * np.arccos(dot))
    gripper = (predicted[..., 7] > 0.5) == (target[..., 7] > 0.5)
    return {"translation_mm": translation, "rotation_deg": rotation, "gripper_correct": gripper}


def summarise(errors: list[dict[str, np.ndarray]], phases: list[int] | None = None,
              tasks: list[int] | None = None) -> dict:
    """Means over all frames and horizon steps of :func:`chunk_errors` results (one per frame, each ``(T,)``), the
    first horizon step's mean translation error, and standard errors over frames (``*_sem``); with ``phases`` (each
    frame's :attr:`LiveFrame.phase`), ``by_phase``: the mean translation error (mm) and frame count of each third of
    the live episodes; with ``tasks`` (each frame's task number, 0 … tasks − 1), ``translation_mm_by_task``: each
    task's mean translation error (mm), in task order."""
    translation = np.concatenate([e["translation_mm"].ravel() for e in errors])
    rotation = np.concatenate([e["rotation_deg"].ravel() for e in errors])
    gripper = np.concatenate([e["gripper_correct"].ravel() for e in errors])
    first = np.array([e["translation_mm"].reshape(-1)[0] for e in errors])
    frame_translation = np.array([e["translation_mm"].mean() for e in errors])  # (frames,) each frame's mean

    def sem(per_frame: np.ndarray) -> float:  # standard error over frames of the per-frame mean (frames: the samples)
        return round(float(per_frame.std(ddof=1) / math.sqrt(len(per_frame))), 3) if len(per_frame) > 1 else 0.0

    def one_per_frame(labels: list[int], what: str) -> np.ndarray:
        if len(labels) != len(errors):
            raise ValueError(f"one {what} per frame: {len(labels)} {what}s for {len(errors)} frames")
        return np.asarray(labels)

    summary = {
        "translation_mm": round(float(translation.mean()), 3),
        "translation_mm_sem": sem(frame_translation),
        "translation_mm_first_step": round(float(first.mean()), 3),
        "rotation_deg": round(float(rotation.mean()), 3),
        "rotation_deg_sem": sem(np.array([e["rotation_deg"].mean() for e in errors])),
        "gripper_accuracy": round(float(gripper.mean()), 4),
        "frames": len(errors),
        "steps": int(translation.size),
    }
    if phases is not None:
        phase_of_frame = one_per_frame(phases, "phase")
        summary["by_phase"] = {}
        for index, name in enumerate(THIRDS):
            chosen = frame_translation[phase_of_frame == index]
            summary["by_phase"][name] = {"translation_mm": round(float(chosen.mean()), 3) if chosen.size else None,
                                         "frames": int(chosen.size)}
    if tasks is not None:
        task_of_frame = one_per_frame(tasks, "task")
        summary["translation_mm_by_task"] = [round(float(frame_translation[task_of_frame == task].mean()), 3)
                                             for task in range(int(task_of_frame.max()) + 1)]
    return summary


# ---------------------------------------------------------------------------------------------------- data
def load_held_out_tasks(root: str | Path, num_tasks: int, frames_per_task: int, horizon: int, seed: int,
                        repo_id: str | None = None) -> list[HeldOutTask]:
    """The first ``num_tasks`` pseudo-tasks of the pseudo-demonstration dataset at ``root`` (each with ≥ 2 episodes),
    with ``frames_per_task`` seeded frames (all when shorter) of each live (last) episode; ``EvaluationError`` /
    ``DemonstrationError`` / ``ActionErrorError`` naming the problem."""
    if num_tasks < 1 or frames_per_task < 1:
        raise ActionErrorError(f"tasks and frames-per-task must be at least 1, got {num_tasks}, {frames_per_task}")
    root = check_pseudo_demo_root(root)
    dataset = open_demo_dataset(repo_id or f"local/{root.name}", root)
    usable = [(task, episodes) for task, episodes in episodes_by_task(dataset) if len(episodes) >= 2]
    if len(usable) < num_tasks:
        raise ActionErrorError(
            f"asked for {num_tasks} pseudo-tasks but the dataset at {root} has {len(usable)} with at least 2 episodes "
            f"(one live, ≥ 1 context)"
        )
    held_out = []
    for task_number, (task, episodes) in enumerate(usable[:num_tasks]):
        demos = [read_demonstration(dataset, episode_index, task) for episode_index in episodes]
        live = demos.pop()
        rng = np.random.default_rng([seed, task_number])
        count = min(frames_per_task, live.num_frames)
        chosen = np.sort(rng.choice(live.num_frames, size=count, replace=False))
        frames = []
        for t in chosen.tolist():
            steps = np.minimum(np.arange(t, t + horizon), live.num_frames - 1)
            noise_seed = int(np.random.SeedSequence([seed, task_number, t]).generate_state(1)[0])
            phase = int(third_of(t, live.num_frames))
            frames.append(LiveFrame(t, live.points_world[t], live.state[t], live.action[steps], noise_seed, phase))
        held_out.append(HeldOutTask(task, episodes[-1], demos, frames, live))
    return held_out


# ---------------------------------------------------------------------------------------------------- inference
def predict_task(policy: InstantPolicyPolicy, held_out: HeldOutTask, k: int, n: int) -> list[np.ndarray]:
    """``(T, 8)`` predictions at every frame of ``held_out`` with K = ``k`` DDIM steps (context of ``n``
    demonstrations already set), one frame at a time with its own seeded generator; a policy that starts from the
    replay (``replay_init_strength``) from the frame's replay prior (:meth:`HeldOutTask.replay_priors`)."""
    device = next(policy.parameters()).device
    config = policy.config
    priors = held_out.replay_priors(n, config.horizon, config.replay_plan()) if config.replay_init_strength \
        else [None] * len(held_out.frames)
    predictions = []
    for frame, prior in zip(held_out.frames, priors, strict=True):
        batch = {POINTCLOUD_KEY: torch.from_numpy(frame.points[None]).to(device),
                 STATE_KEY: torch.from_numpy(frame.state[None]).to(device), "task": [held_out.task]}
        generator = torch.Generator(device="cpu").manual_seed(frame.noise_seed)
        initial = None if prior is None else torch.from_numpy(prior[None]).to(device)
        chunk = policy.predict_action_chunk(batch, generator=generator, num_inference_steps=k,
                                            initial_actions=initial)
        predictions.append(chunk[0].double().cpu().numpy())
    return predictions


def evaluate_setting(policy: InstantPolicyPolicy, tasks: list[HeldOutTask], setting: tuple[int, int, int]) -> dict:
    """Summary of :func:`chunk_errors` over all tasks' frames at ``setting`` = ``(K, N, L)``: each task's first N
    demonstrations at L waypoints as the context, K DDIM steps; ``ms_per_prediction`` times the predictions alone."""
    k, n, l = setting
    errors, seconds = [], 0.0
    for held_out in tasks:
        policy.set_demonstrations(held_out.demos[:n], num_waypoints=l)
        start = time.perf_counter()
        predictions = predict_task(policy, held_out, k, n)
        seconds += time.perf_counter() - start
        errors += [chunk_errors(p, f.target.astype(np.float64)) for p, f in zip(predictions, held_out.frames)]
    phases = [frame.phase for held_out in tasks for frame in held_out.frames]
    return {"K": k, "N": n, "L": l, **summarise(errors, phases, task_of_frames(tasks)),
            "ms_per_prediction": round(1000 * seconds / len(errors), 1)}


def task_of_frames(tasks: list[HeldOutTask]) -> list[int]:
    """The task number (index in ``tasks``) of every frame of ``tasks``, in the order the frames are evaluated."""
    return [number for number, held in enumerate(tasks) for _ in held.frames]


def hold_reference(tasks: list[HeldOutTask]) -> dict:
    """Errors of predicting the current state ``(8,)`` for every horizon step (no model)."""
    frames = [f for held in tasks for f in held.frames]
    errors = [chunk_errors(np.repeat(f.state[None].astype(np.float64), len(f.target), axis=0),
                           f.target.astype(np.float64)) for f in frames]
    return summarise(errors, [f.phase for f in frames], task_of_frames(tasks))


def replay_reference(tasks: list[HeldOutTask], num_demos: int, horizon: int, plan: str) -> dict:
    """Errors of the replay priors themselves (:meth:`HeldOutTask.replay_priors` from ``num_demos``
    demonstrations), what a policy that starts from them is compared with."""
    frames = [f for held in tasks for f in held.frames]
    priors = [prior for held in tasks for prior in held.replay_priors(num_demos, horizon, plan)]
    errors = [chunk_errors(prior.astype(np.float64), f.target.astype(np.float64)) for prior, f in zip(priors, frames)]
    return summarise(errors, [f.phase for f in frames], task_of_frames(tasks))


def swapped_context(tasks: list[HeldOutTask]) -> list[HeldOutTask]:
    """Each task with the next task's demonstrations (the last with the first's), relabelled as its own (and replay
    priors planned from them)."""
    if len(tasks) < 2:
        raise ActionErrorError("the context swap needs at least 2 pseudo-tasks")
    return [
        dataclasses.replace(held, demos=[dataclasses.replace(demo, task=held.task)
                                         for demo in tasks[(index + 1) % len(tasks)].demos], _plans={}, _priors={})
        for index, held in enumerate(tasks)
    ]


def _ratio(numerator: float | None, denominator: float | None) -> float | None:
    """``numerator / denominator`` to 3 decimals; None when either is missing or the denominator is not positive."""
    if numerator is None or denominator is None or denominator <= 0:
        return None
    return round(numerator / denominator, 3)


def context_gain(own: dict, swap: dict) -> dict:
    """``swap / own`` of the translation and rotation errors and of the gripper error (1 − accuracy)."""
    return {
        "translation": _ratio(swap["translation_mm"], own["translation_mm"]),
        "rotation": _ratio(swap["rotation_deg"], own["rotation_deg"]),
        "gripper": _ratio(1.0 - swap["gripper_accuracy"], 1.0 - own["gripper_accuracy"]),
    }


def phase_table(own: dict, hold: dict, swap: dict) -> dict:
    """Per third of the live episodes (``by_phase`` of three :func:`summarise` results at one setting): frames, the
    translation error (mm) with the checkpoint's own demonstrations, holding still and the context swap, own / hold
    and the context gain (swap / own)."""
    table = {}
    for name in THIRDS:
        own_mm, hold_mm, swap_mm = (row["by_phase"][name]["translation_mm"] for row in (own, hold, swap))
        table[name] = {"frames": own["by_phase"][name]["frames"], "own_mm": own_mm, "hold_mm": hold_mm,
                       "swap_mm": swap_mm, "over_hold": _ratio(own_mm, hold_mm),
                       "context_gain": _ratio(swap_mm, own_mm)}
    return table


def task_table(tasks: list[HeldOutTask], own: dict, hold: dict, swap: dict) -> list[dict]:
    """One row per pseudo-task of ``tasks``, in their order: its ``task`` string, its ``frames`` and its mean
    translation error (mm) with the checkpoint's own demonstrations, holding still and the context swap (``own_mm``,
    ``hold_mm``, ``swap_mm``: ``translation_mm_by_task`` of three :func:`summarise` results of ``tasks`` at one
    setting)."""
    return [{"task": held.task, "frames": len(held.frames), "own_mm": own_mm, "hold_mm": hold_mm, "swap_mm": swap_mm}
            for held, own_mm, hold_mm, swap_mm in zip(tasks, own["translation_mm_by_task"],
                                                      hold["translation_mm_by_task"],
                                                      swap["translation_mm_by_task"], strict=True)]


def _task_sums(per_task: list[dict], names: tuple[str, ...] = ("own", "hold", "swap")) -> dict[str, np.ndarray]:
    """Each of ``names`` (the table's ``<name>_mm`` columns; default ``own``, ``hold`` and ``swap``): each task's
    translation error summed over its frames (mean × frames), ``(tasks,)``, from a :func:`task_table`."""
    frames = np.array([row["frames"] for row in per_task], dtype=float)
    return {name: frames * np.array([row[f"{name}_mm"] for row in per_task], dtype=float)
            for name in names}


def _ratios(sums: dict[str, np.ndarray], draws: np.ndarray) -> np.ndarray:
    """The :data:`RATIOS` (own / hold, swap / own of the mean translation error over the frames of the tasks in
    ``draws``: task indices ``(tasks,)`` or ``(resamples, tasks)``), ``(2,)`` or ``(2, resamples)``."""
    own, hold, swap = (sums[name][draws].sum(axis=-1) for name in ("own", "hold", "swap"))
    return np.stack([own / hold, swap / own])


def _interval(low: float, high: float) -> list[float] | None:
    """``[low, high]`` to 4 decimals; None where there is no interval (NaN: one task)."""
    return None if math.isnan(low) else [round(low, 4), round(high, 4)]


def _bootstrap_description(tasks: int, resamples: int, seed: int) -> dict:
    """What an interval of :func:`task_intervals` or :func:`paired_ratio_difference` resampled, for its JSON."""
    return {"unit": "task", "clusters": tasks, "resamples": resamples, "seed": seed, "confidence": CONFIDENCE,
            "method": "percentile cluster bootstrap: tasks resampled with replacement, each ratio of mean errors "
                      "recomputed on the resample's frames; null for one task"}


def task_intervals(per_task: list[dict], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> dict:
    """The 95% cluster bootstrap intervals over tasks (:func:`.bootstrap.cluster_bootstrap`) of the :data:`RATIOS`
    of a :func:`task_table`: ``vs_holding_still`` (own / hold) and ``context_gain_translation`` (swap / own), each
    ``[low, high]`` (None for one task), with what was resampled (``unit``, ``clusters``, ``resamples``, ``seed``,
    ``confidence``, ``method``)."""
    sums = _task_sums(per_task)
    intervals = {}
    for index, name in enumerate(RATIOS):
        low, high = cluster_bootstrap(lambda draws: _ratios(sums, draws)[index], len(per_task), resamples, seed)
        intervals[name] = _interval(low, high)
    return {**intervals, **_bootstrap_description(len(per_task), resamples, seed)}


def _check_paired(a: dict, b: dict) -> None:
    """``ActionErrorError`` unless results ``a`` and ``b`` hold per-task tables of the same held-out frames."""
    for name, result in (("a", a), ("b", b)):
        missing = [key for key in PAIRED_KEYS if key not in result]
        if missing:
            raise ActionErrorError(f"result {name} lacks {', '.join(missing)} (a result from before per-task errors "
                                   f"were kept): it cannot be paired")
    for key in ("seed", "frames_per_task", "horizon_T"):
        if a[key] != b[key]:
            raise ActionErrorError(f"the results differ in {key} ({a[key]} and {b[key]}): other frames, not paired")
    tasks_a = [(row["task"], row["frames"]) for row in a["per_task"]]
    tasks_b = [(row["task"], row["frames"]) for row in b["per_task"]]
    if tasks_a != tasks_b:
        index, (task_a, task_b) = next((index, pair) for index, pair in enumerate(zip_longest(tasks_a, tasks_b))
                                       if pair[0] != pair[1])
        raise ActionErrorError(f"the results were run on different tasks ({len(tasks_a)} and {len(tasks_b)}; task "
                               f"{index}, as (task, frames): {task_a} and {task_b}): not paired")
    for row_a, row_b in zip(a["per_task"], b["per_task"]):
        if abs(row_a["hold_mm"] - row_b["hold_mm"]) > HOLD_TOLERANCE_MM:
            raise ActionErrorError(f"holding still's error on {row_a['task']} differs ({row_a['hold_mm']} and "
                                   f"{row_b['hold_mm']} mm): other frames under the same task, not paired")


def paired_ratio_difference(a: dict, b: dict, resamples: int = BOOTSTRAP_RESAMPLES,
                            seed: int = BOOTSTRAP_SEED) -> dict:
    """a − b of each of the :data:`RATIOS` for two results of :func:`action_error` (or any dicts with their
    :data:`PAIRED_KEYS`) on the same held-out frames, e.g. two checkpoints, with a 95% cluster bootstrap interval
    over tasks: the tasks are resampled jointly (the same draws for both), both ratios recomputed on each resample
    and their difference taken. Per ratio: ``a``, ``b`` (the ratios of the per-task tables), ``difference`` and
    ``ci95`` (``[low, high]``, None for one task); then what was resampled, as :func:`task_intervals`.

    ``ActionErrorError`` when either lacks a per-task table, or they differ in seed, frames per task, horizon, the
    tasks (strings and frame counts, in order) or holding still's error on a task (more than
    :data:`HOLD_TOLERANCE_MM`: other frames)."""
    _check_paired(a, b)
    sums_a, sums_b = _task_sums(a["per_task"]), _task_sums(b["per_task"])
    tasks = len(a["per_task"])
    every = np.arange(tasks)
    ratios_a, ratios_b = _ratios(sums_a, every), _ratios(sums_b, every)
    result = {}
    for index, name in enumerate(RATIOS):
        low, high = cluster_bootstrap(lambda draws: _ratios(sums_a, draws)[index] - _ratios(sums_b, draws)[index],
                                      tasks, resamples, seed)
        result[name] = {"a": round(float(ratios_a[index]), 4), "b": round(float(ratios_b[index]), 4),
                        "difference": round(float(ratios_a[index] - ratios_b[index]), 4),
                        "ci95": _interval(low, high)}
    return {**result, **_bootstrap_description(tasks, resamples, seed)}


def check_setting(config, setting: tuple[int, int, int], samples_per_prediction: int | None = None) -> None:
    """``setting`` = ``(K, N, L)`` and ``samples_per_prediction`` (S) judged by the config's own range checks (those
    :class:`~..configuration_instant_policy.InstantPolicyConfig` makes when it is built, :mod:`..model.bounds`):
    ``config`` with them in it is built and dropped; ``ActionErrorError`` with the config's message."""
    k, n, l = setting
    values = {"inference_steps": k, "num_demos": n, "num_waypoints": l}
    if samples_per_prediction is not None:
        values["samples_per_prediction"] = samples_per_prediction
    try:
        dataclasses.replace(config, **values)
    except ValueError as error:
        raise ActionErrorError(f"unsupported setting K={k}, N={n}, L={l}: {error}") from error


@dataclasses.dataclass
class Probe:
    """A checkpoint loaded for the action error (``policy``, in eval mode), its held-out ``tasks`` and ``description``:
    what the result reports of the checkpoint, the dataset and the frames."""

    policy: InstantPolicyPolicy
    tasks: list[HeldOutTask]
    description: dict


def open_probe(policy_path: str | Path, root: str | Path, settings: list[tuple[int, int, int]], tasks: int = 12,
               frames_per_task: int = 4, seed: int = 0, repo_id: str | None = None, device: str = "cpu",
               samples_per_prediction: int | None = None, replay_init_strength: float | None = None,
               replay_per_object: bool | None = None, replay_anchored: bool | None = None) -> Probe:
    """The checkpoint at ``policy_path`` and the first ``tasks`` held-out pseudo-tasks at ``root``, once every
    ``(K, N, L)`` of ``settings`` is known to be evaluable: in the config's ranges (:func:`check_setting`, before the
    weights load), N below each task's episodes, the dataset's clouds the checkpoint's size. ``samples_per_prediction``,
    ``replay_init_strength``, ``replay_per_object`` and ``replay_anchored`` replace the checkpoint's (None: kept). ``ActionErrorError`` /
    ``EvaluationError`` / ``DemonstrationError`` naming the problem."""
    config = checkpoint_config(Checkpoint(step=0, path=Path(policy_path)))
    for setting in settings:
        check_setting(config, setting, samples_per_prediction)
    overrides = {name: value for name, value in (("samples_per_prediction", samples_per_prediction),
                                                 ("replay_init_strength", replay_init_strength),
                                                 ("replay_per_object", replay_per_object),
                                                 ("replay_anchored", replay_anchored)) if value is not None}
    try:
        dataclasses.replace(config, **overrides)
    except ValueError as error:
        raise ActionErrorError(str(error)) from error
    policy = load_policy(policy_path, device, **overrides)
    config = policy.config
    held_out = load_held_out_tasks(root, tasks, frames_per_task, config.horizon, seed, repo_id)
    fewest = min(len(task.demos) for task in held_out)
    largest = max(n for _, n, _ in settings)
    if largest > fewest:
        raise ActionErrorError(
            f"N={largest} context demonstrations asked, but a pseudo-task at {root} has only {fewest + 1} episodes: "
            f"its last is the live episode, so N can be at most {fewest} (demos per task − 1)"
        )
    if held_out[0].frames[0].points.shape[0] != config.num_points:
        raise ActionErrorError(f"the dataset's clouds have {held_out[0].frames[0].points.shape[0]} points, the "
                               f"checkpoint expects {config.num_points}")
    description = {
        "checkpoint": str(policy_path), "root": str(root), "device": device, "torch_threads": torch.get_num_threads(),
        "tasks": len(held_out), "frames_per_task": frames_per_task,
        "frames": sum(len(task.frames) for task in held_out), "horizon_T": config.horizon, "seed": seed,
        "checkpoint_defaults": {"K": config.inference_steps, "N": config.num_demos, "L": config.num_waypoints},
        "samples_per_prediction": config.samples_per_prediction,
        "replay_init_strength": config.replay_init_strength, "replay_per_object": config.replay_per_object,
        "replay_plan": config.replay_plan(),
    }
    return Probe(policy, held_out, description)


def references(probe: Probe, own: dict, untrained: bool = True) -> dict:
    """The references at the setting of ``own`` (an :func:`evaluate_setting` row of ``probe``): ``swap`` (another
    task's demonstrations), ``context_gain`` (swap / own), ``untrained`` (the same config freshly initialised,
    ``torch.manual_seed(0)``; only with ``untrained``), ``hold`` (predicting the current state), ``phases``
    (:func:`phase_table`), ``per_task`` (:func:`task_table`) and ``intervals`` (:func:`task_intervals`); for a
    policy that starts from the replay, also ``replay`` (the replay priors' own errors, :func:`replay_reference`),
    each task's ``replay_mm`` and the intervals of ``vs_replay`` (own / replay) and ``replay_vs_holding_still``."""
    setting = (own["K"], own["N"], own["L"])
    result = {"swap": evaluate_setting(probe.policy, swapped_context(probe.tasks), setting)}
    result["context_gain"] = context_gain(own, result["swap"])
    if untrained:
        device = next(probe.policy.parameters()).device
        with torch.random.fork_rng(devices=[]), contextlib.redirect_stdout(sys.stderr):  # caller's RNG untouched
            torch.manual_seed(0)
            fresh = InstantPolicyPolicy(dataclasses.replace(probe.policy.config)).to(device).eval()
        result["untrained"] = evaluate_setting(fresh, probe.tasks, setting)
    result["hold"] = hold_reference(probe.tasks)
    result["phases"] = phase_table(own, result["hold"], result["swap"])
    result["per_task"] = task_table(probe.tasks, own, result["hold"], result["swap"])
    result["intervals"] = task_intervals(result["per_task"])
    config = probe.policy.config
    if config.replay_init_strength:
        result["replay"] = replay_reference(probe.tasks, own["N"], config.horizon, config.replay_plan())
        for row, replay_mm, held in zip(result["per_task"], result["replay"]["translation_mm_by_task"], probe.tasks,
                                        strict=True):
            row["replay_mm"] = replay_mm
            row["replay_wrong"] = held.replay_is_wrong(own["N"], config.replay_plan())
        result["intervals"].update(replay_intervals(result["per_task"]))
        result["by_replay"] = replay_split(result["per_task"])
    return result


def replay_split(per_task: list[dict]) -> dict:
    """The tasks whose replay plan is right and those whose plan is wrong (each row's ``replay_wrong``,
    :func:`~..replay.segments.plan_is_wrong` against the live demonstration), apart: for each, its
    ``tasks`` and, where it has two or more, the ratios over holding still of the policy (``vs_holding_still``)
    and of the replay (``replay_vs_holding_still``) and the policy over the replay (``vs_replay``), each
    ``{"value", "ci95"}`` over that group's tasks. A corrector should keep a right start (``vs_replay`` near 1 or
    below) and mend a wrong one (``vs_replay`` well below 1)."""
    split = {}
    for name, wrong in (("right", False), ("wrong", True)):
        rows = [row for row in per_task if row["replay_wrong"] == wrong]
        split[name] = {"tasks": len(rows)}
        if len(rows) < 2:
            continue
        sums = _task_sums(rows, ("own", "hold"))
        low, high = cluster_bootstrap(lambda draws: sums["own"][draws].sum(axis=-1) / sums["hold"][draws].sum(axis=-1),
                                      len(rows), BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
        every = np.arange(len(rows))
        split[name]["vs_holding_still"] = {
            "value": round(float(sums["own"][every].sum() / sums["hold"][every].sum()), 4), "ci95": _interval(low, high)}
        split[name].update(replay_intervals(rows))
    return split


def replay_intervals(per_task: list[dict], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED) -> dict:
    """The ratios ``vs_replay`` (own / replay) and ``replay_vs_holding_still`` (replay / hold) of the mean translation
    errors of a :func:`task_table` with ``replay_mm``, each ``{"value", "ci95"}`` (tasks resampled as in
    :func:`task_intervals`)."""
    sums = _task_sums(per_task, ("own", "hold", "replay"))
    every = np.arange(len(per_task))
    result = {}
    for name, (numerator, denominator) in {"vs_replay": ("own", "replay"),
                                           "replay_vs_holding_still": ("replay", "hold")}.items():
        def ratio(draws, numerator=numerator, denominator=denominator):
            return sums[numerator][draws].sum(axis=-1) / sums[denominator][draws].sum(axis=-1)

        low, high = cluster_bootstrap(ratio, len(per_task), resamples, seed)
        result[name] = {"value": round(float(ratio(every)), 4), "ci95": _interval(low, high)}
    return result


def action_error(policy_path: str | Path, root: str | Path, tasks: int = 12, frames_per_task: int = 4, seed: int = 0,
                 k: int = DEFAULT_K, n: int = DEFAULT_N, l: int = DEFAULT_L, untrained: bool = True,
                 repo_id: str | None = None, device: str = "cpu", samples_per_prediction: int | None = None,
                 replay_init_strength: float | None = None, replay_per_object: bool | None = None,
                 replay_anchored: bool | None = None) -> dict:
    """Action errors of the checkpoint at ``policy_path`` on held-out pseudo-tasks at ``root`` at K = ``k``, N = ``n``,
    L = ``l`` (module docstring).

    Returns a JSON-ready dict: ``settings`` (one row, that setting's errors), the references of :func:`references`
    (``swap``, ``context_gain``, ``untrained`` with ``untrained``, ``hold``, ``phases``, ``per_task``,
    ``intervals``), the dataset and sample description and the wall time. Raises ``ActionErrorError`` /
    ``EvaluationError`` / ``DemonstrationError`` on bad input (a value outside the config's ranges, N ≥ demos per
    task, …).
    """
    start = time.perf_counter()
    probe = open_probe(policy_path, root, [(k, n, l)], tasks, frames_per_task, seed, repo_id, device,
                       samples_per_prediction, replay_init_strength, replay_per_object, replay_anchored)
    own = evaluate_setting(probe.policy, probe.tasks, (k, n, l))
    result = {**probe.description, "settings": [own], **references(probe, own, untrained)}
    result["wall_s"] = round(time.perf_counter() - start, 1)
    return result
