"""How far a replay plan lies from what the demonstrator did in the same live scene: the error of the prior an
``instant_policy`` starts from, where ground truth exists.

A demonstration recorded in a scene is that scene's ground truth (the suite's scripted demonstrator, MetaWorld's
expert, a pseudo-task's live demonstration). :func:`plan_error` plans the replay of context demonstrations onto the
live demonstration's first cloud as inference does (:func:`~..replay.priors.plan_onto_live`, one of
:data:`~..replay.plan.REPLAY_PLANS`) and measures it at the live demonstration's bottleneck poses, the ends of its
segments (:func:`~..replay.segments.segment_ends`), where a wrong plan fails a task:

* a gripper change (``"gripper"``) is matched to the plan's gripper change of the same order and kind (the k-th
  close to the k-th close); a live change the plan lacks counts as a ``missed`` gripper change;
* a stop, a turn (``"waypoint"``) and the last action (``"end"``) are matched to the planned action of the plan
  step the live demonstration has reached at that frame (:func:`~..replay.timing.plan_steps` on its states): the
  plan's pace is not an error.

Each bottleneck gives the translation (m) and rotation (rad) between the planned and the demonstrated commanded EE
pose; the rotation is the smaller of the two a parallel gripper cannot tell apart (turned half a turn about its
approach axis, EE z, it grasps alike). :func:`error_quantiles` pools them into the median and 90th percentile per kind,
and counts the wrong plans (:func:`~..replay.segments.plan_is_wrong`: off by 30 mm or more at a gripper change
or the end, or missing a gripper change), the criterion the stream also judges its training priors by.

The prior itself is measured as the network is trained against it: at every live frame ``t`` the ``T`` planned
actions read at the plan step the live demonstration has reached (:func:`~..replay.priors.replay_priors` at
:func:`~..replay.timing.plan_steps`, as the stream reads a training prior) against the live actions ``t … t + T − 1``,
the mean translation over the chunk, beside holding the live state still. :func:`error_quantiles` reports their ratio
(``prior_vs_holding_still``) over every frame and per third of the live episode: a demonstrator's free approach from
its own start pose falls in the first third.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..contract import poses_from_vectors
from ..data.demonstrations import Demonstration
from ..geometry.se3 import pose_distance, rotation_angle
from ..replay.plan import ReplayPlan
from ..replay.priors import plan_onto_live, replay_priors
from ..replay.segments import gripper_change_kinds, plan_is_wrong, segment_ends
from ..replay.timing import plan_steps

BOTTLENECK_KINDS = ("gripper", "waypoint", "end")
THIRDS = ("first_third", "middle_third", "last_third")  # of a live episode, by frame
HALF_TURN_ABOUT_Z = np.diag([-1.0, -1.0, 1.0])  # the parallel gripper's symmetry, in the EE frame


def plan_error(context: Sequence[Demonstration], live: Demonstration, plan: str, horizon: int = 8) -> dict:
    """The error of the ``plan`` replay of ``context`` in ``live``'s scene at ``live``'s bottleneck poses (module
    docstring): ``{"bottlenecks": [{"frame", "kind", "translation_m", "rotation_rad"}, ...], "missed": int,
    "wrong": bool, "demo_index": int, "chunks": {"prior_m", "hold_m"}}`` (``wrong``:
    :func:`~..replay.segments.plan_is_wrong`; ``demo_index``: the context demonstration the plan replays;
    ``chunks``: ``(F,)`` each, the mean translation over the ``horizon`` actions ahead of every live frame of the
    prior read there and of holding the live state)."""
    replay = plan_onto_live(live.task, list(context), live.points_world[0], plan)
    planned = replay.actions.astype(np.float64)
    live_action = live.action.astype(np.float64)
    ends = segment_ends(live_action)
    aligned = plan_steps(live.state, planned)
    live_changes = gripper_change_kinds(live_action)
    plan_changes = gripper_change_kinds(planned)
    rows, missed = [], 0
    for end in ends.tolist():
        if end in live_changes:
            kind_of_change, order = live_changes[end]
            same = [step for step, (kind, k) in plan_changes.items() if kind == kind_of_change and k == order]
            if not same:
                missed += 1
                continue
            step, kind = same[0], "gripper"
        else:
            step, kind = int(aligned[end]), "end" if end == len(live_action) - 1 else "waypoint"
        T_planned, _ = poses_from_vectors(planned[step])
        T_live, _ = poses_from_vectors(live_action[end])
        translation, rotation = pose_distance(T_planned, T_live)
        rotation = min(rotation, rotation_angle(T_planned[:3, :3] @ HALF_TURN_ABOUT_Z, T_live[:3, :3]))
        rows.append({"frame": end, "kind": kind, "translation_m": float(translation), "rotation_rad": float(rotation)})
    return {"bottlenecks": rows, "missed": missed, "wrong": plan_is_wrong(planned, live_action),
            "demo_index": replay.demo_index, "chunks": chunk_errors(replay, aligned, live, horizon)}


def chunk_errors(replay: ReplayPlan, aligned: np.ndarray, live: Demonstration, horizon: int) -> dict:
    """``{"prior_m", "hold_m"}``, ``(F,)`` each: at every frame of ``live``, the mean distance (m) over the live
    actions ``t … t + horizon − 1`` (the last one held) of the prior read at plan step ``aligned[t]`` and of the
    live state ``t``."""
    frames = len(live.action)
    ahead = np.minimum(np.arange(frames)[:, None] + np.arange(horizon), frames - 1)  # (F, T)
    targets = live.action[ahead, :3].astype(np.float64)
    priors = replay_priors(replay, aligned, horizon)[..., :3].astype(np.float64)
    hold = live.state[:, None, :3].astype(np.float64)
    return {"prior_m": np.linalg.norm(priors - targets, axis=-1).mean(axis=-1),
            "hold_m": np.linalg.norm(hold - targets, axis=-1).mean(axis=-1)}


def error_quantiles(errors: Sequence[dict]) -> dict:
    """Median and 90th percentile of the translation (mm) and rotation (degrees) of the bottlenecks of
    :func:`plan_error` results, pooled and per kind, with the bottleneck counts, the missed gripper changes, the
    plans and the wrong ones among them (``wrong``)."""
    rows = [row for error in errors for row in error["bottlenecks"]]

    def summary(selected: list[dict]) -> dict:
        if not selected:
            return {"count": 0}
        translation = 1000.0 * np.array([row["translation_m"] for row in selected])
        rotation = np.rad2deg([row["rotation_rad"] for row in selected])
        return {"count": len(selected),
                "translation_mm": {"median": round(float(np.median(translation)), 1),
                                   "p90": round(float(np.percentile(translation, 90)), 1)},
                "rotation_deg": {"median": round(float(np.median(rotation)), 1),
                                 "p90": round(float(np.percentile(rotation, 90)), 1)}}

    result = {"all": summary(rows)}
    result.update({kind: summary([row for row in rows if row["kind"] == kind]) for kind in BOTTLENECK_KINDS})
    result["prior_vs_holding_still"] = prior_ratios(errors)
    result["missed_gripper_changes"] = int(sum(error["missed"] for error in errors))
    result["plans"] = len(errors)
    result["wrong_plans"] = sum(error["wrong"] for error in errors)
    return result


def third_of(frames: np.ndarray, num_frames: int) -> np.ndarray:
    """The third of a live episode of ``num_frames`` frames (0, 1, 2: :data:`THIRDS`) that each of ``frames`` lies in."""
    return np.minimum(len(THIRDS) * np.asarray(frames) // num_frames, len(THIRDS) - 1)


def prior_ratios(errors: Sequence[dict]) -> dict:
    """The prior's chunk error over holding still (the sums over frames of :func:`chunk_errors`), over every frame
    (``all``) and per third of each live episode (:data:`THIRDS`), with the frames counted."""
    prior, hold, third = [], [], []
    for error in errors:
        frames = len(error["chunks"]["prior_m"])
        prior.append(error["chunks"]["prior_m"])
        hold.append(error["chunks"]["hold_m"])
        third.append(third_of(np.arange(frames), frames))
    if not prior:
        return {"frames": 0}
    prior, hold, third = np.concatenate(prior), np.concatenate(hold), np.concatenate(third)

    def ratio(selected: np.ndarray) -> float | None:
        return round(float(prior[selected].sum() / hold[selected].sum()), 3) if hold[selected].sum() > 0 else None

    result = {"frames": len(prior), "all": ratio(np.ones(len(prior), dtype=bool))}
    result.update({name: ratio(third == index) for index, name in enumerate(THIRDS)})
    return result


__all__ = ["BOTTLENECK_KINDS", "THIRDS", "chunk_errors", "error_quantiles", "plan_error", "prior_ratios", "third_of"]
