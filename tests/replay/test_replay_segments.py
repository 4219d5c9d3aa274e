"""Segments of a demonstration and their anchors (``replay/segments.py``): a segment ends at a gripper change,
a stop, a turn and the last action; it is anchored to the object its end approaches, a release never to the object
just grasped, and a segment that ends in free space keeps the anchor before it."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_instant_policy.replay.segments import SegmentConfig, anchor_segments, plan_is_wrong, segment_ends

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # xyzw: a half turn about x, pointing the gripper down


def actions_through(points: list[tuple[float, float, float, float]], steps: int = 5) -> np.ndarray:
    """``(F, 8)``: straight lines of ``steps`` actions between consecutive ``(x, y, z, gripper)`` points, the gripper
    of each point from its first action on."""
    rows = [np.concatenate([points[0][:3], DOWN, [points[0][3]]])]
    for (x0, y0, z0, _), (x1, y1, z1, gripper) in zip(points[:-1], points[1:], strict=True):
        for fraction in np.linspace(0.0, 1.0, steps + 1)[1:]:
            position = (1 - fraction) * np.array([x0, y0, z0]) + fraction * np.array([x1, y1, z1])
            rows.append(np.concatenate([position, DOWN, [gripper]]))
    return np.asarray(rows)


def blob(center: tuple[float, float, float], seed: int) -> np.ndarray:
    """``(200, 3)``: points within 2 cm of ``center``."""
    return np.asarray(center) + np.random.default_rng(seed).uniform(-0.02, 0.02, (200, 3))


def test_segments_end_at_turns_gripper_changes_stops_and_the_last_action():
    actions = actions_through([(0.4, 0.0, 0.3, 1), (0.4, 0.0, 0.1, 1), (0.6, 0.0, 0.1, 1)])  # down, then across
    np.testing.assert_array_equal(segment_ends(actions), [5, 10])
    closing = actions.copy()
    closing[7:, 7] = 0.0  # the gripper closes at action 7, halfway across
    np.testing.assert_array_equal(segment_ends(closing), [5, 7, 10])
    waiting = np.concatenate([actions[:8], np.repeat(actions[8:9], 3, axis=0), actions[8:]])  # waits at action 8
    np.testing.assert_array_equal(segment_ends(waiting), [5, 8, 13])


def test_a_gentle_curve_is_one_segment_and_bad_actions_are_refused():
    t = np.linspace(0.0, 1.0, 20)
    actions = np.zeros((20, 8))
    actions[:, 0], actions[:, 2] = 0.4 + 0.2 * t, 0.2 + 0.005 * np.sin(np.pi * t)  # 5 mm off the chord: no turn
    actions[:, 3:7], actions[:, 7] = DOWN, 1.0
    np.testing.assert_array_equal(segment_ends(actions, SegmentConfig(turn_tolerance=0.01)), [19])
    with pytest.raises(ValueError, match=r"\(F, 8\)"):
        segment_ends(np.zeros((5, 7)))
    with pytest.raises(ValueError, match="positive"):
        SegmentConfig(anchor_radius=0.0)


def test_grasp_carry_and_release_are_anchored_to_the_grasped_then_the_other_object():
    """Down onto object 0, close, lift, carry over object 1, lower, open, retreat up: the approach and the grasp on
    object 0, the lowering and the release on object 1; the lift, the carry and the retreat end in free space, in
    transit (``-1``)."""
    objects = [blob((0.40, 0.0, 0.02), seed=0), blob((0.55, 0.0, 0.02), seed=1)]
    actions = actions_through([(0.40, 0.0, 0.25, 1), (0.40, 0.0, 0.04, 1), (0.40, 0.0, 0.04, 0), (0.40, 0.0, 0.25, 0),
                               (0.55, 0.0, 0.25, 0), (0.55, 0.0, 0.06, 0), (0.55, 0.0, 0.06, 1), (0.55, 0.0, 0.30, 1)])
    segments = anchor_segments(actions, objects)
    assert segments is not None
    closing, opening = 6, 26  # the first actions with the new gripper command
    # the descent ends at 5 where the EE waits for the close (a stop); lift top 15, carry end 20, lowered 25
    np.testing.assert_array_equal(segments.ends, [5, closing, 15, 20, 25, opening, 35])
    np.testing.assert_array_equal(segments.anchors, [0, 0, -1, -1, 1, 1, -1])
    ends, anchors = segments.anchored()
    np.testing.assert_array_equal(ends, [5, closing, 25, opening])
    np.testing.assert_array_equal(anchors, [0, 0, 1, 1])


def test_a_release_is_never_anchored_to_the_object_just_grasped():
    """The place lies nearer to the grasped object's first place than to the other object: the release still
    anchors on the other one."""
    objects = [blob((0.40, 0.0, 0.02), seed=0), blob((0.60, 0.0, 0.02), seed=1)]
    actions = actions_through([(0.40, 0.0, 0.04, 1), (0.40, 0.0, 0.04, 0), (0.45, 0.0, 0.10, 0), (0.45, 0.0, 0.10, 1)])
    segments = anchor_segments(actions, objects)
    assert segments is not None
    np.testing.assert_array_equal(segments.ends, [1, 10, 11, 15])  # close, carry end, release, the last
    np.testing.assert_array_equal(segments.anchors, [0, -1, 1, -1])


def test_a_held_object_anchors_the_segment_where_it_meets_another_object():
    """A rod grasped near one end, the close commanded 12 cm above it while the EE still descends, lifted, carried and
    lowered until its far end meets a block 16 cm from the EE: the carry's end and the last segment are anchored to
    the block, which the EE itself never comes within ``anchor_radius`` of; the grasp stays on the rod. Carrying the
    rod from where the close was commanded instead of from where the EE reached it would leave it 12 cm too low, in
    transit."""
    rng = np.random.default_rng(2)
    rod = np.column_stack([rng.uniform(0.30, 0.50, 400), rng.uniform(-0.01, 0.01, 400), rng.uniform(0.01, 0.03, 400)])
    objects = [rod, blob((0.10, 0.0, 0.02), seed=1)]
    actions = actions_through([(0.45, 0.0, 0.25, 1), (0.45, 0.0, 0.15, 1), (0.45, 0.0, 0.15, 0), (0.45, 0.0, 0.03, 0),
                               (0.45, 0.0, 0.08, 0), (0.28, 0.0, 0.08, 0), (0.28, 0.0, 0.03, 0)])
    segments = anchor_segments(actions, objects)
    assert segments is not None
    closing, lowest, lifted, carried, last = 6, 15, 20, 25, 30
    np.testing.assert_array_equal(segments.ends, [5, closing, lowest, lifted, carried, last])
    np.testing.assert_array_equal(segments.anchors, [-1, 0, 0, -1, 1, 1])
    ee_to_block = np.linalg.norm(objects[1][None] - actions[[carried, last], None, :3], axis=-1).min(axis=1)
    assert np.all(ee_to_block > SegmentConfig().anchor_radius)


def test_nothing_approached_gives_no_segments():
    objects = [blob((0.40, 0.0, 0.02), seed=0)]
    actions = actions_through([(0.40, 0.0, 0.40, 1), (0.60, 0.0, 0.40, 1)])
    assert anchor_segments(actions, objects) is None
    assert anchor_segments(actions, []) is None


def test_a_plan_is_wrong_where_a_gripper_change_or_the_end_is_off_or_a_change_is_missing():
    """Judged against the demonstration of the same scene: the same actions are right, a path that swerves between
    the bottlenecks too (demonstrators differ there), a grasp 5 cm off, an end 5 cm off or a grasp never made are
    wrong."""
    demonstrated = actions_through([(0.4, 0.0, 0.2, 1.0), (0.5, 0.1, 0.05, 0.0), (0.5, -0.1, 0.2, 0.0),
                                    (0.45, -0.1, 0.05, 1.0)])
    assert not plan_is_wrong(demonstrated, demonstrated)
    swerving = demonstrated.copy()
    swerving[7:9, 2] += 0.08  # mid-carry, no gripper change there
    assert not plan_is_wrong(swerving, demonstrated)
    grasp = int(np.flatnonzero(demonstrated[1:, 7] != demonstrated[:-1, 7])[0]) + 1
    off_at_grasp = demonstrated.copy()
    off_at_grasp[grasp, 0] += 0.05
    assert plan_is_wrong(off_at_grasp, demonstrated)
    off_at_end = demonstrated.copy()
    off_at_end[-1, 1] += 0.05
    assert plan_is_wrong(off_at_end, demonstrated)
    never_grasps = demonstrated.copy()
    never_grasps[:, 7] = 1.0
    assert plan_is_wrong(never_grasps, demonstrated)
