"""``workbench/scripts/lid_grasp.py``: an episode's grasp, slip and fall-back read from its per-step record."""

import numpy as np

from workbench.scripts.lid_grasp import summary, totals


def _episode(rise_mm: float, angles: list[float], close_at: int = 2):
    """A lid opened from step ``close_at + 1`` on, the EE held on the handle or drawn ``rise_mm`` off it."""
    steps = len(angles)
    ee_lid = np.tile([0.14, 0.0, 0.0325], (steps, 1))
    ee_lid[close_at + 4:, 2] += rise_mm * 1e-3
    closed = np.arange(steps) >= close_at
    return ee_lid, np.array(angles, dtype=float), closed


def test_a_hand_that_keeps_the_handle_has_not_slipped():
    row = summary(*_episode(0.0, [0, 0, 0, 10, 20, 30, 40, 50, 55, 55]), [4.0, 5.0], True)
    assert row["slip_mm"] == 0.0 and row["grasp_z_mm"] == 32.5
    assert row["max_deg"] == 55.0 and not row["fell_back"]
    assert row["close_lag_mm"] == [4.0, 5.0]


def test_fingers_drawn_off_the_handle_count_as_slipped_and_a_pushed_back_lid_as_fallen():
    row = summary(*_episode(15.0, [0, 0, 0, 10, 20, 30, 33, 33, 30, 25]), [8.0, 9.0], False)
    assert row["slip_mm"] == 15.0
    assert row["fell_back"] and row["end_deg"] == 25.0
    after_the_largest_angle = summary(*_episode(15.0, [0, 0, 0, 10, 30, 20, 20, 20, 20, 20]), [8.0, 9.0], False)
    assert after_the_largest_angle["slip_mm"] == 0.0
    kept = summary(*_episode(0.0, [0, 0, 0, 10, 20, 30, 40, 50, 55, 55]), [4.0, 5.0], True)
    assert totals([row, kept]) == {"episodes": 2, "successes": 1, "median_close_lag_mm": 7.0,
                                   "median_grasp_z_mm": 32.5, "slipped": 1, "fell_back": 1}


def test_an_episode_that_never_closes_has_no_grasp():
    ee_lid, angles, closed = _episode(0.0, [0] * 6)
    row = summary(ee_lid, angles, np.zeros_like(closed), None, False)
    assert row["slip_mm"] is None and row["grasp_z_mm"] is None and row["close_lag_mm"] is None


def test_a_gripper_that_reopens_before_it_held_the_handle_has_not_slipped():
    ee_lid, angles, closed = _episode(15.0, [0, 0, 0, 10, 20, 30, 40, 50, 55, 55])
    closed[5:] = False  # closed at step 2, open again from the step it would have held
    assert summary(ee_lid, angles, closed, [4.0, 5.0], False)["slip_mm"] == 0.0
