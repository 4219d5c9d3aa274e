"""Rendering, pseudo-task sampling and pseudo-demonstration replay (pybullet renderer, small scenes)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.geometry.se3 import (
    invert,
    look_rotation,
    make_pose,
    pose_distance,
    pose_from_pos_quat,
    transform_points,
)
from lerobot_instant_policy.objects.library import is_held_out, load_object
from lerobot_instant_policy.objects.rendering import PointCloudRenderer, RenderConfig, default_cameras
from lerobot_instant_policy.objects.splatting import SplatConfig, SplatRenderer
from lerobot_instant_policy.pseudo_demos.replay import (
    DemoConfig,
    GenerationError,
    frames_in_view,
    hold_signature,
    plan_demo,
    render_demo,
    sample_layout,
    shift_layout,
    splat_demo,
)
from lerobot_instant_policy.pseudo_demos.tasks import (
    FAMILIES,
    GRASP_REACH,
    INTERPOLATIONS,
    TEMPLATES,
    sample_pseudo_task,
)
from lerobot_instant_policy.pseudo_demos.trajectory import MAX_STEP_ROTATION, MAX_STEP_TRANSLATION

OBJECT_IDS = ("prim/box_0", "prim/cylinder_0")
SURFACE_TOLERANCE = 0.0035  # rasterisation at ≤ 128-pixel crops puts points up to ~3 mm off the surface
FLOAT32_SLACK = 1e-5


@pytest.fixture(scope="module")
def objects():
    return [load_object(object_id) for object_id in OBJECT_IDS]


_SURFACE_TREES: dict[str, cKDTree] = {}


def _surface_tree(model) -> cKDTree:
    """A KD-tree over a dense (≈ 0.5 mm spacing) sample of the object's surface, in its own frame."""
    if model.object_id not in _SURFACE_TREES:
        mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
        dense, _ = trimesh.sample.sample_surface(mesh, 200_000, seed=0)
        _SURFACE_TREES[model.object_id] = cKDTree(dense)
    return _SURFACE_TREES[model.object_id]


def _surface_distances(points, labels, objects, T_world_objects) -> np.ndarray:
    """Distance of every labelled world point to the surface of the object its label names."""
    distances = np.full(len(points), np.inf)
    for index, (model, pose) in enumerate(zip(objects, T_world_objects, strict=True)):
        mask = labels == index
        if mask.any():
            local = transform_points(invert(pose), np.asarray(points[mask], dtype=np.float64))
            distances[mask] = _surface_tree(model).query(local)[0]
    return distances


SCENE_POSES = [
    make_pose([0.45, 0.12, 0.0], Rotation.from_euler("z", 0.3)),
    make_pose([0.56, -0.12, 0.0], Rotation.from_euler("z", -1.0)),
]
GRIPPER_AWAY = make_pose([0.5, 0.0, 1.5], look_rotation(np.array([0.0, 0.0, -1.0]), 0.0))


# ------------------------------------------------------------------------------------------- renderer


def test_rendered_points_lie_on_the_objects(renderer, objects):
    renderer.set_objects(objects)
    points, labels = renderer.render(SCENE_POSES, GRIPPER_AWAY, True)
    assert points.dtype == np.float32 and labels.dtype == np.int8
    assert points.shape == (len(labels), 3)
    assert set(np.unique(labels).tolist()) == {0, 1}
    distances = _surface_distances(points, labels, objects, SCENE_POSES)
    assert np.median(distances) < 0.002
    assert np.percentile(distances, 99) < SURFACE_TOLERANCE
    assert distances.max() < 0.005
    # each object is seen as a whole (every camera's crop covers it), not just a sliver
    for index, (model, pose) in enumerate(zip(objects, SCENE_POSES, strict=True)):
        local = transform_points(invert(pose), points[labels == index].astype(np.float64))
        spread = local.max(axis=0) - local.min(axis=0)
        assert np.all(spread >= 0.9 * model.extents), (model.object_id, spread, model.extents)


def test_gripper_occludes_but_is_never_in_the_cloud(renderer, objects):
    renderer.set_objects(objects)
    box_top = SCENE_POSES[0] @ make_pose([0.0, 0.0, objects[0].extents[2] + 0.005])
    # gripper just above the box, pointing down, in view of every camera
    T_world_ee = make_pose(box_top[:3, 3], look_rotation(np.array([0.0, 0.0, -1.0]), 0.4))
    clear, clear_labels = renderer.render(SCENE_POSES, GRIPPER_AWAY, True)
    for gripper_open in (True, False):
        points, labels = renderer.render(SCENE_POSES, T_world_ee, gripper_open)
        assert set(np.unique(labels).tolist()) <= {0, 1}
        distances = _surface_distances(points, labels, objects, SCENE_POSES)
        assert distances.max() < 0.005
        # the gripper hides part of the box
        assert (labels == 0).sum() < (clear_labels == 0).sum()
        # nothing from the gripper's body above the box is in the cloud: every point is below the taller
        # object's top, and no point labelled as the box rises above the box
        assert points[:, 2].max() < max(model.extents[2] for model in objects) + 0.003
        assert points[labels == 0, 2].max() < objects[0].extents[2] + 0.003


def test_objects_out_of_view_give_an_empty_cloud(renderer, objects):
    renderer.set_objects(objects)
    far = [make_pose([20.0, 0.0, 0.0]), make_pose([20.0, 0.5, 0.0])]
    points, labels = renderer.render(far, GRIPPER_AWAY, True)
    assert points.shape == (0, 3) and labels.shape == (0,)
    below = [make_pose([0.5, 0.0, -50.0]), make_pose([0.5, 0.3, -50.0])]
    assert len(renderer.render(below, GRIPPER_AWAY, True)[0]) == 0


def test_render_rejects_wrong_number_of_poses(renderer, objects):
    renderer.set_objects(objects)
    with pytest.raises(ValueError, match="expected 2 object poses"):
        renderer.render(SCENE_POSES[:1], GRIPPER_AWAY, True)


def test_surface_cloud_is_the_complete_unoccluded_surface(renderer, objects):
    """``cloud="surface"``: every object's whole surface sample in its pose, the gripper hides nothing."""
    with PointCloudRenderer(RenderConfig(cloud="surface")) as surface_renderer:
        surface_renderer.set_objects(objects)
        box_top = SCENE_POSES[0] @ make_pose([0.0, 0.0, objects[0].extents[2] + 0.005])
        T_world_ee = make_pose(box_top[:3, 3], look_rotation(np.array([0.0, 0.0, -1.0]), 0.4))
        away, away_labels = surface_renderer.render(SCENE_POSES, GRIPPER_AWAY, True)
        near, near_labels = surface_renderer.render(SCENE_POSES, T_world_ee, False)
    assert away.dtype == np.float32 and away_labels.dtype == np.int8
    np.testing.assert_array_equal(away, near)
    np.testing.assert_array_equal(away_labels, near_labels)
    for index, (model, pose) in enumerate(zip(objects, SCENE_POSES, strict=True)):
        assert (away_labels == index).sum() == len(model.surface_points)
        local = transform_points(invert(pose), away[away_labels == index].astype(np.float64))
        np.testing.assert_allclose(local, model.surface_points, atol=1e-5)
    # the cameras see only part of the box (its bottom faces the table): part of the surface is far from every
    # rendered point
    renderer.set_objects(objects)
    seen, seen_labels = renderer.render(SCENE_POSES, GRIPPER_AWAY, True)
    gaps = cKDTree(seen[seen_labels == 0]).query(away[away_labels == 0])[0]
    assert (gaps > 0.01).mean() > 0.05


def test_render_config_rejects_unknown_cloud_source():
    with pytest.raises(ValueError, match="cloud must be one of"):
        RenderConfig(cloud="lidar")


# ---------------------------------------------------------------------------------------- pseudo-tasks


def test_sample_pseudo_task_distribution(objects):
    other_pair = [load_object("pb/duck"), load_object("prim/drawer_1")]
    templates = []
    for seed in range(200):
        pair = objects if seed % 2 == 0 else other_pair
        task = sample_pseudo_task(f"t{seed}", pair, np.random.default_rng(seed))
        templates.append(task.template)
        assert task.object_ids == (pair[0].object_id, pair[1].object_id)
        assert 2 <= len(task.waypoints) <= 6
        assert task.gripper_changes() >= 1
        for waypoint in task.waypoints:
            assert waypoint.anchor in (0, 1)
            assert waypoint.interpolation in INTERPOLATIONS
            rotation = waypoint.T_anchor_ee[:3, :3]
            np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
            assert np.linalg.det(rotation) == pytest.approx(1.0)
            np.testing.assert_array_equal(waypoint.T_anchor_ee[3], [0, 0, 0, 1])
        if task.template in ("grasp", "pick_and_place", "pull", "hinge"):
            # the closing waypoint is within grasp reach of its object's surface
            close = next(w for w in task.waypoints if not w.gripper_open)
            model = pair[close.anchor]
            reach = np.linalg.norm(model.surface_points - close.T_anchor_ee[:3, 3], axis=1).min()
            assert reach <= GRASP_REACH
    random_share = templates[:60].count("random") / 60
    assert 0.3 <= random_share <= 0.7
    assert set(TEMPLATES) <= set(templates)
    assert set(templates) <= set(TEMPLATES) | {"random"}


def test_sample_pseudo_task_biased_fraction_and_determinism(objects):
    assert all(
        sample_pseudo_task("t", objects, np.random.default_rng(s), biased_fraction=0.0).template == "random"
        for s in range(20)
    )
    assert all(
        sample_pseudo_task("t", objects, np.random.default_rng(s), biased_fraction=1.0).template != "random"
        for s in range(20)
    )
    first = sample_pseudo_task("t", objects, np.random.default_rng(9))
    second = sample_pseudo_task("t", objects, np.random.default_rng(9))
    assert first.template == second.template
    for a, b in zip(first.waypoints, second.waypoints, strict=True):
        np.testing.assert_array_equal(a.T_anchor_ee, b.T_anchor_ee)
        assert (a.anchor, a.gripper_open, a.interpolation) == (b.anchor, b.gripper_open, b.interpolation)


def test_task_families_of_the_ladder(objects):
    for seed in range(40):
        reach = sample_pseudo_task("r", objects, np.random.default_rng(seed), family="reach")
        assert reach.template == "reach" and len(reach.waypoints) == 1 and reach.gripper_changes() == 0
        assert reach.waypoints[0].T_anchor_ee[2, 3] >= 0.03  # above the table
        grip = sample_pseudo_task("g", objects, np.random.default_rng(seed), family="reach_grip")
        closing, retreat = grip.waypoints
        assert grip.gripper_changes() == 1 and not closing.gripper_open and not retreat.gripper_open
        assert closing.anchor == retreat.anchor
        model = objects[closing.anchor]
        assert np.linalg.norm(model.surface_points - closing.T_anchor_ee[:3, 3], axis=1).min() <= GRASP_REACH
        lift = retreat.T_anchor_ee[:3, 3] - closing.T_anchor_ee[:3, 3]
        assert 0.05 <= lift[2] <= 0.15 and np.linalg.norm(lift[:2]) <= 0.08 + 1e-9
        place = sample_pseudo_task("p", objects, np.random.default_rng(seed), family="grasp_place")
        assert place.template == "grasp_place" and len(place.waypoints) == 6 and place.gripper_changes() == 2
    # the motion is drawn per task: on the same objects, tasks differ in anchor or pose
    targets = {
        (task.waypoints[0].anchor, *np.round(task.waypoints[0].T_anchor_ee[:3, 3], 4))
        for task in (sample_pseudo_task("r", objects, np.random.default_rng(seed), family="reach") for seed in range(20))
    }
    assert len(targets) == 20
    assert {task.waypoints[0].anchor for task in
            (sample_pseudo_task("r", objects, np.random.default_rng(s), family="reach") for s in range(20))} == {0, 1}
    assert FAMILIES[-1] == "full"
    with pytest.raises(ValueError, match="unknown pseudo-task family 'climb'"):
        sample_pseudo_task("x", objects, np.random.default_rng(0), family="climb")


def _roll_about_approach(T_anchor_ee: np.ndarray) -> float:
    """The turn (degrees) of a gripper pose about its approach axis from ``look_rotation``'s reference roll."""
    reference = look_rotation(T_anchor_ee[:3, 2], 0.0)
    return float(np.degrees(Rotation.from_matrix(reference.T @ T_anchor_ee[:3, :3]).as_rotvec()[2]))


def test_waypoint_roll_bound_turns_every_gripper_pose_within_it(objects):
    """``waypoint_max_roll_deg`` bounds each drawn gripper pose's turn about its approach (0: the reference roll);
    180, the default, allows any turn."""
    rolls = {0.0: [], 30.0: [], 180.0: []}
    for seed in range(30):
        for family in ("reach", "reach_grip"):
            for bound in rolls:
                task = sample_pseudo_task("t", objects, np.random.default_rng(seed), family=family,
                                          waypoint_max_roll_deg=bound)
                rolls[bound] += [_roll_about_approach(waypoint.T_anchor_ee) for waypoint in task.waypoints]
    assert np.abs(rolls[0.0]).max() < 1e-6
    assert np.abs(rolls[30.0]).max() <= 30.0 + 1e-6 and np.abs(rolls[30.0]).max() > 20.0
    assert np.abs(rolls[180.0]).max() > 150.0
    with pytest.raises(ValueError, match=r"waypoint_max_roll_deg must lie in \[0, 180\] degrees, got 200"):
        sample_pseudo_task("x", objects, np.random.default_rng(0), family="reach", waypoint_max_roll_deg=200.0)


# --------------------------------------------------------------------------------------- demonstrations


def make_demo(task, objects, renderer, rng, config, expected_signature=None, T_world_objects_start=None):
    """Plan a demonstration from ``rng`` with the default cameras, then render it (clouds resampled from a stream of
    their own)."""
    plan = plan_demo(task, objects, rng, config, default_cameras(), expected_signature, T_world_objects_start)
    return render_demo(task, objects, plan, renderer, np.random.default_rng(7), config.num_points)


@pytest.fixture(scope="module")
def pick_task(objects):
    assert not any(is_held_out(object_id) for object_id in OBJECT_IDS)
    for seed in range(200):
        task = sample_pseudo_task(f"pick_{seed}", objects, np.random.default_rng(seed))
        if task.template == "pick_and_place":
            return task
    pytest.fail("no pick_and_place task in 200 seeds")


@pytest.fixture(scope="module")
def demo_pair(pick_task, objects, renderer):
    """Two demonstrations of the pick-and-place task with the default (augmented) config."""
    first = make_demo(pick_task, objects, renderer, np.random.default_rng(100), DemoConfig())
    signature = hold_signature(pick_task, first.layout, objects)
    second = make_demo(
        pick_task, objects, renderer, np.random.default_rng(101), DemoConfig(), expected_signature=signature
    )
    return first, second, signature


@pytest.fixture(scope="module")
def clean_pair(pick_task, objects, renderer):
    """Two demonstrations without disturbances or gripper faults (frames follow the reference path)."""
    config = DemoConfig(disturbance_probability=0.0, gripper_fault_fraction=0.0)
    first = make_demo(pick_task, objects, renderer, np.random.default_rng(200), config)
    signature = hold_signature(pick_task, first.layout, objects)
    second = make_demo(pick_task, objects, renderer, np.random.default_rng(201), config, expected_signature=signature)
    return first, second, signature


def _state_poses(vectors: np.ndarray) -> np.ndarray:
    return np.stack([pose_from_pos_quat(vector[:3], vector[3:7]) for vector in vectors.astype(np.float64)])


def _check_arrays(demo) -> None:
    frames = demo.num_frames
    assert frames > 10
    assert demo.points.shape == (frames, 2048, 3) and demo.points.dtype == np.float32
    assert np.isfinite(demo.points).all()
    assert demo.point_labels.shape == (frames, 2048)
    assert set(np.unique(demo.point_labels).tolist()) <= {0, 1}
    assert demo.T_world_objects.shape == (frames, 2, 4, 4)
    assert demo.held_object.shape == (frames,)
    for vectors in (demo.state, demo.action):
        assert vectors.shape == (frames, 8) and vectors.dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(vectors[:, 3:7], axis=1), 1.0, atol=1e-5)
        assert np.all(vectors[:, 6] >= 0.0)  # canonical hemisphere
        assert set(np.unique(vectors[:, 7]).tolist()) <= {0.0, 1.0}
    # the gripper both opens and closes, i.e. the task's changes survived
    assert {0.0, 1.0} == set(np.unique(demo.state[:, 7]).tolist())


def _check_motion_bounds(demo) -> None:
    states = _state_poses(demo.state)
    actions = _state_poses(demo.action)
    translation, rotation = pose_distance(states[:-1], states[1:])
    assert translation.max() <= MAX_STEP_TRANSLATION + FLOAT32_SLACK
    assert rotation.max() <= MAX_STEP_ROTATION + 1e-3  # float32 quaternions: ~1e-4 rad of noise
    translation, rotation = pose_distance(states, actions)
    assert translation.max() <= MAX_STEP_TRANSLATION + FLOAT32_SLACK
    assert rotation.max() <= MAX_STEP_ROTATION + 1e-3


def test_demo_arrays_and_motion_bounds(demo_pair):
    for demo in demo_pair[:2]:
        _check_arrays(demo)
        _check_motion_bounds(demo)


def test_demo_points_lie_on_tracked_objects(demo_pair, objects):
    """Every frame's points sit on the surfaces of the objects at their tracked poses."""
    for demo in demo_pair[:2]:
        for frame in range(0, demo.num_frames, 3):
            distances = _surface_distances(
                demo.points[frame], demo.point_labels[frame], objects, demo.T_world_objects[frame]
            )
            assert np.percentile(distances, 99) < SURFACE_TOLERANCE, frame
            assert distances.max() < 0.006, frame


def test_held_object_moves_with_the_gripper(demo_pair):
    first, second, signature = demo_pair
    assert max(signature) >= 0, f"the pick-and-place task grasped nothing: {signature}"
    for demo in (first, second):
        held_frames = np.flatnonzero(demo.held_object >= 0)
        assert len(held_frames) > 5
        held = int(demo.held_object[held_frames[0]])
        assert np.all(demo.held_object[held_frames] == held)  # one object for the whole hold
        assert np.all(np.diff(held_frames) == 1)  # a single contiguous hold
        states = _state_poses(demo.state)
        start, end = held_frames[0], held_frames[-1]
        assert np.linalg.norm(states[end, :3, 3] - states[start, :3, 3]) > 0.05

        # ground truth: the object's pose in the EE frame is constant while held, fault frames included
        rigid = held_frames
        assert len(rigid) > 5
        relative = invert(states[rigid]) @ demo.T_world_objects[rigid, held]
        translation, rotation = pose_distance(relative, relative[:1])
        assert translation.max() < 1e-4 and rotation.max() < 1e-3

        # observation: the held object's points, in the EE frame, stay put
        def ee_centroid(frame):
            mask = demo.point_labels[frame] == held
            assert mask.sum() > 100
            return transform_points(invert(states[frame]), demo.points[frame][mask].astype(np.float64)).mean(axis=0)

        assert np.linalg.norm(ee_centroid(start) - ee_centroid(end)) < 0.015

        # the other object never moves; the held one rests before the grasp and after the release
        other = 1 - held
        world = demo.T_world_objects
        np.testing.assert_array_equal(world[:, other], np.broadcast_to(world[0, other], world[:, other].shape))
        np.testing.assert_allclose(world[0, other], demo.layout.T_world_objects[other])
        np.testing.assert_allclose(world[:start, held], np.broadcast_to(demo.layout.T_world_objects[held], world[:start, held].shape))
        np.testing.assert_array_equal(world[end:, held], np.broadcast_to(world[end, held], world[end:, held].shape))
        moved, _ = pose_distance(demo.T_world_objects[-1, held], demo.layout.T_world_objects[held])
        assert moved > 0.02


def test_held_object_follows_the_gripper_on_fault_frames(demo_pair):
    demo = demo_pair[0]
    held_frames = np.flatnonzero(demo.held_object >= 0)
    faults = held_frames[demo.state[held_frames, 7] == 1.0]
    assert len(faults) > 0  # the default 10 % fault fraction puts some inside the hold
    held = int(demo.held_object[held_frames[0]])
    states = _state_poses(demo.state)
    relative = invert(states[held_frames]) @ demo.T_world_objects[held_frames, held]
    translation, _ = pose_distance(relative, relative[:1])
    assert translation.max() < 1e-4


def _check_waypoints_reached(demo, task) -> None:
    for waypoint, frame in zip(task.waypoints, demo.waypoint_frames, strict=True):
        target = demo.layout.T_world_objects[waypoint.anchor] @ waypoint.T_anchor_ee
        position, quat = demo.state[frame, :3], demo.state[frame, 3:7]
        np.testing.assert_allclose(position, target[:3, 3], atol=1e-4)
        expected_quat = Rotation.from_matrix(target[:3, :3]).as_quat()
        assert min(np.abs(quat - expected_quat).max(), np.abs(quat + expected_quat).max()) < 1e-4
        after = min(frame + 1, demo.num_frames - 1)
        assert demo.state[after, 7] == float(waypoint.gripper_open)


def test_waypoints_are_reached_in_every_demo(clean_pair, pick_task, objects):
    first, second, signature = clean_pair
    assert max(signature) >= 0
    assert hold_signature(pick_task, second.layout, objects) == signature
    # different scenes...
    shift, _ = pose_distance(first.layout.T_world_objects, second.layout.T_world_objects)
    assert shift.min() > 0.01
    # ...same waypoints relative to the objects
    for demo in (first, second):
        _check_arrays(demo)
        _check_motion_bounds(demo)
        assert len(demo.waypoint_frames) == len(pick_task.waypoints)
        assert list(demo.waypoint_frames) == sorted(demo.waypoint_frames)
        _check_waypoints_reached(demo, pick_task)


def test_waypoints_are_reached_with_default_augmentation(demo_pair, pick_task):
    for demo in demo_pair[:2]:
        _check_waypoints_reached(demo, pick_task)


def test_same_seed_gives_identical_demo_with_a_fresh_renderer(demo_pair, pick_task, objects):
    reference = demo_pair[0]
    with PointCloudRenderer() as fresh:
        # a renderer that already showed other objects (different body ids, cached shapes) gives the same demo
        fresh.set_objects([load_object("prim/torus_3"), load_object("pb/duck")])
        again = make_demo(pick_task, objects, fresh, np.random.default_rng(100), DemoConfig())
    for name in ("points", "point_labels", "state", "action", "T_world_objects", "held_object"):
        assert np.array_equal(getattr(again, name), getattr(reference, name)), name
    assert again.waypoint_frames == reference.waypoint_frames
    np.testing.assert_array_equal(again.layout.T_world_objects, reference.layout.T_world_objects)


def test_generation_error_when_objects_never_in_view(pick_task, objects, renderer):
    config = DemoConfig(object_x_range=(20.0, 20.1), max_scene_attempts=2)
    with pytest.raises(GenerationError, match=r"no valid scene in 2 attempts \(a frame had no object in view\)"):
        make_demo(pick_task, objects, renderer, np.random.default_rng(0), config)


def test_frames_in_view_agree_with_what_pybullet_renders(renderer, objects):
    """The planning-time view check (no rendering) says a frame is in view exactly where pybullet's cameras see an
    object: both objects on the table, one of them carried far away, both far away."""
    renderer.set_objects(objects)
    far = make_pose([20.0, 0.0, 0.0], Rotation.identity())
    scenes = [SCENE_POSES, [SCENE_POSES[0], far], [far, far]]
    in_view = frames_in_view(objects, np.stack([np.stack(poses) for poses in scenes]), default_cameras())
    assert in_view.tolist() == [True, True, False]
    for poses, seen in zip(scenes, in_view, strict=True):
        assert (len(renderer.render(poses, GRIPPER_AWAY, True)[0]) > 0) == seen


def test_rendering_keeps_the_plan_and_draws_from_its_own_stream(pick_task, objects, renderer):
    """A planned demonstration rendered with two different resampling streams: the same trajectory, objects and
    waypoint frames as planned; the clouds differ only in which points were kept."""
    plan = plan_demo(pick_task, objects, np.random.default_rng(300), DemoConfig(), default_cameras())
    again = plan_demo(pick_task, objects, np.random.default_rng(300), DemoConfig(), default_cameras())
    np.testing.assert_array_equal(again.state, plan.state)
    first, second = (
        render_demo(pick_task, objects, plan, renderer, np.random.default_rng(seed), 512) for seed in (1, 2)
    )
    for demo in (first, second):
        for name in ("state", "action", "T_world_objects", "held_object", "waypoint_frames"):
            np.testing.assert_array_equal(getattr(demo, name), getattr(plan, name), err_msg=name)
        assert demo.points.shape == (plan.num_frames, 512, 3)
    assert not np.array_equal(first.points, second.points)


def test_splatting_keeps_the_plan_whatever_the_frames_per_call(pick_task, objects, single_torch_thread):
    """A planned demonstration splatted (coarse sizes) 7 or 64 frames per call: the same clouds and labels, the plan
    kept, every point on the object its label names."""
    plan = plan_demo(pick_task, objects, np.random.default_rng(300), DemoConfig(), default_cameras())
    renderer = SplatRenderer(SplatConfig(zbuffer_resolution=(160, 120)))
    first, second = (
        splat_demo(pick_task, objects, plan, renderer, np.random.default_rng(1), 256, 1024, frames_per_call)
        for frames_per_call in (7, 64)
    )
    np.testing.assert_array_equal(first.points, second.points)
    np.testing.assert_array_equal(first.point_labels, second.point_labels)
    for name in ("state", "action", "T_world_objects", "held_object", "waypoint_frames"):
        np.testing.assert_array_equal(getattr(first, name), getattr(plan, name), err_msg=name)
    assert first.points.shape == (plan.num_frames, 256, 3) and first.point_labels.shape == (plan.num_frames, 256)
    for frame in range(0, plan.num_frames, 10):
        distances = _surface_distances(first.points[frame], first.point_labels[frame], objects,
                                       plan.T_world_objects[frame])
        # the points are exact surface samples; the distance is to the reference's own ≈ 0.5 mm spaced samples
        assert distances.max() < 2e-3, f"frame {frame}: a point {distances.max() * 1e3:.2f} mm off its object"


def test_a_shared_object_layout_survives_scene_retries(pick_task, objects, renderer):
    """Fixed initial object poses (``--share-object-layout``) are reused on every scene attempt: here every attempt
    fails the same way, and the error says so."""
    far = np.stack([np.eye(4), np.eye(4)])
    far[:, 0, 3] = [20.0, 20.3]
    config = DemoConfig(max_scene_attempts=3)
    with pytest.raises(GenerationError, match=r"no valid scene in 3 attempts \(a frame had no object in view\)"):
        make_demo(pick_task, objects, renderer, np.random.default_rng(0), config, T_world_objects_start=far)


def _layout_angles(objects, config: DemoConfig, count: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Object yaws and start-pose roll angles (deg) of ``count`` sampled layouts; the roll is measured against the
    untilted, unturned top-down pose, so it includes the tilt."""
    rng = np.random.default_rng(0)
    yaws, rolls = [], []
    reference = look_rotation(np.array([0.0, 0.0, -1.0]), 0.0)
    for _ in range(count):
        layout = sample_layout(objects, rng, config)
        yaws += [np.degrees(np.arctan2(T[1, 0], T[0, 0])) for T in layout.T_world_objects]
        rolls.append(np.degrees(Rotation.from_matrix(reference.T @ layout.T_world_ee_start[:3, :3]).magnitude()))
    return np.abs(yaws), np.array(rolls)


def test_layout_yaw_and_start_roll_ranges(objects):
    """``object_max_yaw_deg`` and ``start_max_roll_deg`` bound the layout's turns; the defaults span them fully."""
    yaws, rolls = _layout_angles(objects, DemoConfig(object_max_yaw_deg=30.0, start_max_roll_deg=10.0,
                                                     start_max_tilt_deg=0.0))
    assert yaws.max() <= 30.0 + 1e-6 and yaws.max() > 25.0
    assert rolls.max() <= 10.0 + 1e-6 and rolls.max() > 8.0
    yaws, rolls = _layout_angles(objects, DemoConfig(start_max_tilt_deg=0.0))
    assert yaws.max() > 170.0 and rolls.max() > 85.0


def test_shift_layout_interpolates_position_and_yaw_along_the_shorter_arc():
    T_from = np.stack([make_pose([0.4, 0.1, 0.0], Rotation.from_euler("z", 170, degrees=True)),
                       make_pose([0.5, -0.1, 0.0], Rotation.from_euler("z", 10, degrees=True))])
    T_to = np.stack([make_pose([0.6, -0.1, 0.0], Rotation.from_euler("z", -170, degrees=True)),
                     make_pose([0.5, 0.1, 0.0], Rotation.from_euler("z", 50, degrees=True))])
    assert np.array_equal(shift_layout(T_from, T_to, 0.0), T_from)
    np.testing.assert_allclose(shift_layout(T_from, T_to, 1.0), T_to, atol=1e-12)
    half = shift_layout(T_from, T_to, 0.5)
    np.testing.assert_allclose(half[:, :3, 3], [[0.5, 0.0, 0.0], [0.5, 0.0, 0.0]], atol=1e-12)
    yaws = np.degrees(np.arctan2(half[:, 1, 0], half[:, 0, 0]))
    np.testing.assert_allclose(np.abs(yaws[0]), 180.0, atol=1e-9)  # across ±180°, not back through 0°
    np.testing.assert_allclose(yaws[1], 30.0, atol=1e-9)
    for T in half:  # still proper poses turned about the vertical only
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)
