"""The replay's one timing model (``replay/timing.py``): a live episode that executed the plan exactly is at plan
step t at its frame t, one at half the pace at step t // 2, one that pauses stays at its step; a prior reads T steps
from there, clamped to the plan, shifted where asked."""

from __future__ import annotations

import numpy as np

from lerobot_instant_policy.replay.timing import plan_steps, prior_steps


def plan(length: int = 20, close: int = 12) -> np.ndarray:
    """``(length, 8)``: actions along x, 1 cm apart, gripper open before action ``close``."""
    actions = np.zeros((length, 8))
    actions[:, 0] = np.linspace(0.01, 0.01 * length, length)
    actions[:, 6] = 1.0
    actions[:, 7] = (np.arange(length) < close).astype(float)
    return actions


def executed(actions: np.ndarray) -> np.ndarray:
    """The states ``(G, 8)`` of a robot that executed ``actions`` exactly from the origin: at step t the pose action
    t − 1 commanded."""
    start = actions[:1].copy()
    start[0, 0], start[0, 7] = 0.0, 1.0
    return np.concatenate([start, actions[:-1]])


def test_an_exact_replay_is_at_step_t_at_its_frame_t():
    actions = plan()
    assert np.array_equal(plan_steps(executed(actions), actions), np.arange(20))


def test_a_live_episode_at_another_pace_is_matched_to_the_plan_step_it_has_reached():
    actions = plan()
    states = executed(actions)
    slow = np.repeat(states, 2, axis=0)
    matched = plan_steps(slow, actions)
    assert np.array_equal(matched[4:], np.arange(4, 40) // 2)
    # steps 0 and 1 both stand at a_0 (the plan knows its start only by its first action): so do frames 2 and 3
    assert np.all(matched[:4] <= 1)
    paused = np.concatenate([states[:12], np.repeat(states[11:12], 5, axis=0), states[12:]])  # a pause before closing
    matched = plan_steps(paused, actions)
    assert matched[0] == 0 and matched[-1] == 19 and np.all(np.diff(matched) >= 0)
    assert np.all(matched[11:17] == 11)


def test_a_prior_reads_horizon_steps_clamped_to_the_plan_and_shifted_where_asked():
    steps = np.array([0, 5, 18])
    np.testing.assert_array_equal(prior_steps(steps, 4, 20), [[0, 1, 2, 3], [5, 6, 7, 8], [18, 19, 19, 19]])
    np.testing.assert_array_equal(prior_steps(steps, 3, 20, np.array([-2, 3, 4])), [[0, 0, 0], [8, 9, 10],
                                                                                      [19, 19, 19]])
