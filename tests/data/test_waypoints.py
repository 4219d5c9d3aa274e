"""Waypoint extraction (docs/design.md §5): first and last frame, both sides of every gripper change, stops, then an
even fill along the path; never more than L frames, and a clear error for input it cannot use."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.data.waypoints import StopCriterion, extract_waypoints


def line_path(x: np.ndarray) -> np.ndarray:
    """``(F, 4, 4)`` poses at ``(x, 0, 0)`` with identity rotation."""
    poses = np.tile(np.eye(4), (len(x), 1, 1))
    poses[:, 0, 3] = x
    return poses


def uniform_path(frames: int, step: float = 0.01) -> np.ndarray:
    return line_path(np.arange(frames) * step)


def test_straight_uniform_path_gets_evenly_spaced_waypoints():
    chosen = extract_waypoints(uniform_path(91), np.ones(91), 10)
    assert chosen.dtype == np.int64
    np.testing.assert_array_equal(chosen, np.arange(0, 91, 10))


def test_fill_follows_path_length_not_frame_count():
    # 40 frames crawling 1 mm per frame, then 40 frames moving 1 cm per frame: the fast half is 10x longer.
    x = np.concatenate([np.arange(40) * 0.001, 0.039 + np.arange(1, 41) * 0.01])
    chosen = extract_waypoints(line_path(x), np.ones(len(x)), 10)
    assert (chosen >= 40).sum() >= 7, chosen


def test_both_sides_of_every_gripper_change_are_kept():
    gripper = np.ones(60)
    gripper[17:41] = 0.0  # closes at frame 17, opens again at frame 41
    chosen = extract_waypoints(uniform_path(60), gripper, 8)
    assert len(chosen) == 8 and {0, 16, 17, 40, 41, 59} <= set(chosen.tolist())
    assert np.all(np.diff(chosen) > 0)


def test_a_stop_is_a_waypoint_but_a_single_repeated_frame_is_not():
    held = np.concatenate([np.arange(47) * 0.01, [0.46] * 4, 0.47 + np.arange(40) * 0.01])  # frames 46…50 at rest
    chosen = extract_waypoints(line_path(held), np.ones(len(held)), 10)
    assert 46 in chosen
    repeated = np.concatenate([np.arange(47) * 0.01, [0.46], 0.47 + np.arange(40) * 0.01])  # one duplicated frame
    assert 46 not in extract_waypoints(line_path(repeated), np.ones(len(repeated)), 10)
    assert 46 in extract_waypoints(line_path(repeated), np.ones(len(repeated)), 10, StopCriterion(min_steps=1))


def test_turning_in_place_is_motion_not_a_stop():
    # 20 steps of 1 cm, 20 steps turning 3° in place, 20 steps of 1 cm: 60 equal units of path
    x = np.concatenate([np.arange(21) * 0.01, [0.2] * 20, 0.2 + np.arange(1, 21) * 0.01])
    poses = line_path(x)
    angles = np.concatenate([np.zeros(21), np.arange(1, 21) * 3.0, np.full(20, 60.0)])
    poses[:, :3, :3] = Rotation.from_euler("z", angles[:, None], degrees=True).as_matrix()
    np.testing.assert_array_equal(extract_waypoints(poses, np.ones(len(x)), 5), [0, 15, 30, 45, 60])


def test_never_more_than_L_and_priority_when_mandatory_frames_exceed_it():
    rng = np.random.default_rng(0)
    for _ in range(20):
        frames = int(rng.integers(12, 120))
        gripper = (rng.random(frames) < 0.5).astype(float)  # a change almost every other frame
        num_waypoints = int(rng.integers(2, 12))
        chosen = extract_waypoints(uniform_path(frames), gripper, num_waypoints)
        assert len(chosen) == num_waypoints and len(set(chosen.tolist())) == num_waypoints
        assert chosen[0] == 0 and chosen[-1] == frames - 1 and np.all(np.diff(chosen) > 0)
    # 10 changes, L = 6: the ends, then the first frames of new states, evenly thinned (first and last kept)
    gripper = np.ones(60)
    for start in range(5, 55, 10):
        gripper[start : start + 5] = 0.0
    changes = np.flatnonzero(gripper[1:] != gripper[:-1]) + 1
    chosen = extract_waypoints(uniform_path(60), gripper, 6)
    assert set(chosen.tolist()) - {0, 59} <= set(changes.tolist())
    assert changes[0] in chosen and changes[-1] in chosen


def test_before_change_frames_come_before_stops():
    x = np.concatenate([np.arange(20) * 0.01, [0.19] * 4, 0.2 + np.arange(30) * 0.01])  # rest at frames 19…23
    gripper = np.ones(len(x))
    gripper[40:] = 0.0
    chosen = extract_waypoints(line_path(x), gripper, 4)
    np.testing.assert_array_equal(chosen, [0, 39, 40, len(x) - 1])
    assert 19 in extract_waypoints(line_path(x), gripper, 5)


def test_too_few_frames_is_a_clear_error():
    with pytest.raises(ValueError, match="demonstration of 5 frames cannot give 10 waypoints"):
        extract_waypoints(uniform_path(5), np.ones(5), 10)
    np.testing.assert_array_equal(extract_waypoints(uniform_path(10), np.ones(10), 10), np.arange(10))
    with pytest.raises(ValueError, match="num_waypoints must be at least 2"):
        extract_waypoints(uniform_path(10), np.ones(10), 1)


def test_bad_shapes_and_nan_are_clear_errors():
    with pytest.raises(ValueError, match=r"T_world_ee must have shape \(F, 4, 4\)"):
        extract_waypoints(np.zeros((10, 3, 4)), np.ones(10), 4)
    with pytest.raises(ValueError, match=r"gripper_open must have shape \(F,\) = \(10,\)"):
        extract_waypoints(uniform_path(10), np.ones(9), 4)
    poses = uniform_path(10)
    poses[3, 0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        extract_waypoints(poses, np.ones(10), 4)
    gripper = np.ones(10)
    gripper[2] = np.inf
    with pytest.raises(ValueError, match="NaN or infinite"):
        extract_waypoints(uniform_path(10), gripper, 4)
    with pytest.raises(ValueError, match="min_steps"):
        StopCriterion(min_steps=0)
