"""Reducing a demonstration to ``L`` waypoints (docs/design.md §5, paper §3.1): the frames its context graph is built
from.

Mandatory frames are the first and the last frame, both sides of every gripper change (the first frame that shows
the new state and the last one before it, so a demonstration shows where the gripper acted) and every place the EE
nearly stops; the remaining slots are filled evenly along the path, in proportion to the length of each gap between
mandatory frames. The result never has more than ``L`` frames. When the mandatory frames alone exceed ``L`` they are
kept by priority: first and last frame, then the first frame of each new gripper state, then the frame before each
change, then stops; a group that does not fit whole is thinned evenly over its members (its first and last kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.se3 import pose_distance

# The path length unit: one pseudo-demonstration step (docs/design.md §4).
STEP_TRANSLATION = 0.01
STEP_ROTATION = np.deg2rad(3.0)
# Path length every frame adds on top of its motion, so that a segment where the EE holds still still gets filled
# by frame count (it is tiny against the unit, so moving segments dominate).
FRAME_LENGTH = 1e-3


@dataclass(frozen=True)
class StopCriterion:
    """The EE "nearly stops" where it moves less than ``translation`` (m) and ``rotation`` (rad) per frame for at
    least ``min_steps`` consecutive frame steps. ``min_steps = 2`` ignores a single repeated frame (the pose held
    while the gripper toggles in a pseudo-demonstration, or a gripper-fault frame) but finds a demonstrator that
    waits at a pose for the fingers to close."""

    translation: float = 0.002
    rotation: float = float(np.deg2rad(1.0))
    min_steps: int = 2

    def __post_init__(self) -> None:
        if self.translation < 0 or self.rotation < 0 or self.min_steps < 1:
            raise ValueError(f"a stop criterion needs translation, rotation ≥ 0 and min_steps ≥ 1, got {self}")


def extract_waypoints(
    T_world_ee: np.ndarray,
    gripper_open: np.ndarray,
    num_waypoints: int,
    stop: StopCriterion = StopCriterion(),
) -> np.ndarray:
    """Sorted frame indices ``(L,)`` (int64) of a demonstration's waypoints, ``L = num_waypoints``.

    ``T_world_ee (F, 4, 4)``: EE pose per frame in the world frame. ``gripper_open (F,)``: gripper state per frame,
    1 open and 0 closed (thresholded at 0.5). A gripper change at frame ``t`` (``t`` shows the new state) makes
    frames ``t`` and ``t − 1`` mandatory. A stop is the first frame of a run of nearly still frames (``stop``); a
    run that reaches the last frame, or starts at the first, is already represented by that frame. The free slots
    are spread evenly along the path, measured as the larger of translation in cm and rotation in units of 3° per
    frame step (``_fill_evenly``).

    Raises ``ValueError`` for bad shapes, NaN or infinite values, ``num_waypoints < 2`` and episodes with fewer
    than ``num_waypoints`` frames.
    """
    T_world_ee = np.asarray(T_world_ee, dtype=np.float64)
    gripper_open = np.asarray(gripper_open, dtype=np.float64)
    if T_world_ee.ndim != 3 or T_world_ee.shape[1:] != (4, 4):
        raise ValueError(f"T_world_ee must have shape (F, 4, 4), got {T_world_ee.shape}")
    frames = len(T_world_ee)
    if gripper_open.shape != (frames,):
        raise ValueError(f"gripper_open must have shape (F,) = ({frames},), got {gripper_open.shape}")
    if not (np.isfinite(T_world_ee).all() and np.isfinite(gripper_open).all()):
        raise ValueError("T_world_ee and gripper_open must be finite (found NaN or infinite values)")
    if num_waypoints < 2:
        raise ValueError(f"num_waypoints must be at least 2 (the first and the last frame), got {num_waypoints}")
    if frames < num_waypoints:
        raise ValueError(
            f"a demonstration of {frames} frames cannot give {num_waypoints} waypoints: it needs at least "
            f"{num_waypoints} frames (or use fewer waypoints)"
        )

    translation, rotation = pose_distance(T_world_ee[:-1], T_world_ee[1:])
    is_open = gripper_open > 0.5
    changes = np.flatnonzero(is_open[1:] != is_open[:-1]) + 1
    runs = still_runs((translation < stop.translation) & (rotation < stop.rotation), stop.min_steps)
    stops = [start for start, end in runs if start > 0 and end < frames - 1]  # the first and last frame are in

    chosen = {0, frames - 1}
    for group in (changes, changes - 1, stops):
        candidates = [int(frame) for frame in group if frame not in chosen]
        chosen.update(_thin_evenly(candidates, num_waypoints - len(chosen)))

    step_length = np.maximum(translation / STEP_TRANSLATION, rotation / STEP_ROTATION) + FRAME_LENGTH
    path = np.concatenate([[0.0], np.cumsum(step_length)])
    return _fill_evenly(sorted(chosen), path, num_waypoints)


def still_runs(still: np.ndarray, min_steps: int) -> list[tuple[int, int]]:
    """Every run of at least ``min_steps`` still steps (``still (F − 1,)``: step ``t → t + 1``) as ``(first frame,
    first frame after the run)``: the EE stands still from the one to the other."""
    runs = []
    start = None
    for step, is_still in enumerate(np.append(still, False)):
        if is_still and start is None:
            start = step
        elif not is_still and start is not None:
            if step - start >= min_steps:
                runs.append((start, step))
            start = None
    return runs


def _thin_evenly(candidates: list[int], budget: int) -> list[int]:
    """All ``candidates`` if they fit in ``budget``, else ``budget`` of them evenly spread (ends first)."""
    if budget <= 0:
        return []
    if len(candidates) <= budget:
        return candidates
    picks = np.unique(np.round(np.linspace(0, len(candidates) - 1, budget)).astype(int))
    return [candidates[index] for index in picks]


def _fill_evenly(chosen: list[int], path: np.ndarray, num_waypoints: int) -> np.ndarray:
    """Add frames to ``chosen`` (sorted, includes both ends) until it has ``num_waypoints``.

    The free slots go to the gaps between chosen frames in proportion to their length along ``path (F,)``
    (cumulative; D'Hondt: the next slot goes to the gap with the most length per slot), never more slots than a gap
    has frames. Inside a gap the slots sit at equal fractions of its length, each on the nearest frame that keeps
    them distinct and in order.
    """
    gaps = list(zip(chosen[:-1], chosen[1:]))
    slots = [0] * len(gaps)
    for _ in range(num_waypoints - len(chosen)):
        open_gaps = [index for index, (a, b) in enumerate(gaps) if slots[index] < b - a - 1]
        best = max(open_gaps, key=lambda index: (path[gaps[index][1]] - path[gaps[index][0]]) / (slots[index] + 1))
        slots[best] += 1
    filled = list(chosen)
    for (a, b), count in zip(gaps, slots):
        previous = a
        for slot in range(count):
            target = path[a] + (path[b] - path[a]) * (slot + 1) / (count + 1)
            window = np.arange(previous + 1, b - (count - slot) + 1)
            previous = int(window[np.argmin(np.abs(path[window] - target))])
            filled.append(previous)
    return np.asarray(sorted(filled), dtype=np.int64)
