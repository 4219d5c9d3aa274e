"""The generator end to end: ``lerobot-ip-generate`` writes a LeRobotDataset that honours docs/design.md §4 and §7."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch
from scipy.spatial import cKDTree

from lerobot_instant_policy.cli.generate import main as generate_main
from lerobot_instant_policy.contract import POSE_GRIPPER_NAMES
from lerobot_instant_policy.data.lerobot_format import read_episode
from lerobot_instant_policy.geometry.se3 import (
    invert,
    look_rotation,
    pose_distance,
    pose_from_pos_quat,
    transform_points,
)
from lerobot_instant_policy.objects.library import load_object

REPO_ID = "local/test_pseudo"


def _generate(out, *extra: str) -> int:
    return generate_main(["--out", str(out), "--repo-id", REPO_ID, "--no-progress", *extra])


# The module's dataset: two tasks of the full family (seed 37: a pull and a grasp, so that every demonstration carries
# an object), two demonstrations each, a shard per task.
ARGUMENTS = ("--num-tasks", "2", "--demos-per-task", "2", "--seed", "37", "--tasks-per-shard", "1")


@pytest.fixture(scope="module")
def interrupted_and_resumed(tmp_path_factory):
    """The module's dataset written the hard way: its first shard by this process, then an interruption (the second
    shard half written), which a plain run must refuse to overwrite, then resumed with 2 worker processes (the
    second shard and the merge). Returns the output and what each step gave; the resume test checks them and that the
    result is the dataset one uninterrupted worker writes."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.cli.generate import build_parser, config_from_args
    from lerobot_instant_policy.pseudo_demos.generation import generate_shard, prepare_output, shard_ranges

    out = tmp_path_factory.mktemp("gen") / "pseudo"
    config = config_from_args(build_parser().parse_args(["--out", str(out), "--repo-id", REPO_ID, *ARGUMENTS]))
    prepare_output(config, overwrite=False, resume=False)
    finished = generate_shard(config, 0, shard_ranges(config)[0])
    (out / ".shards" / "shard-00001.tmp" / "data").mkdir(parents=True)
    finished_episodes = LeRobotDataset(f"{REPO_ID}-shard-00000", root=finished).meta.total_episodes
    plain_code = _generate(out, *ARGUMENTS)
    resumed_code = _generate(out, *ARGUMENTS, "--workers", "2", "--resume")
    return {"out": out, "finished_episodes": finished_episodes, "plain_code": plain_code, "resumed_code": resumed_code}


@pytest.fixture(scope="module")
def dataset_dir(interrupted_and_resumed):
    assert interrupted_and_resumed["resumed_code"] == 0
    return interrupted_and_resumed["out"]


def _cheap_clouds(directory) -> str:
    """A generation config file whose clouds cost next to nothing: 32 points per frame from the objects' complete
    surface samples (``render.cloud = "surface"``: nothing rendered). For the tests that read only the task and scene
    records or the states and actions, whose properties hold whatever the clouds."""
    path = directory / "cheap_clouds.json"
    path.write_text(json.dumps({"demo": {"num_points": 32}, "render": {"cloud": "surface"}}))
    return str(path)


@pytest.fixture(scope="module")
def episodes(dataset_dir):
    """Per episode: task, points (F, 2048, 3), state (F, 8), action (F, 8) read back through LeRobotDataset."""
    from lerobot.datasets import LeRobotDataset

    dataset = LeRobotDataset(REPO_ID, root=dataset_dir)
    return [read_episode(dataset, index) for index in range(dataset.meta.total_episodes)]


def _poses(vectors: np.ndarray) -> np.ndarray:
    return np.stack([pose_from_pos_quat(vector[:3], vector[3:7]) for vector in vectors])


def test_dataset_loads_and_matches_the_contract(dataset_dir):
    from lerobot.datasets import LeRobotDataset

    dataset = LeRobotDataset(REPO_ID, root=dataset_dir)
    assert dataset.meta.total_episodes == 4
    assert len(dataset.meta.tasks) == 2
    features = dataset.meta.features
    assert features["observation.pointcloud"]["dtype"] == "float32"
    assert tuple(features["observation.pointcloud"]["shape"]) == (2048, 3)
    for key in ("observation.state", "action"):
        assert features[key]["dtype"] == "float32"
        assert tuple(features[key]["shape"]) == (8,)
        assert features[key]["names"] == POSE_GRIPPER_NAMES
    frame = dataset[0]
    assert frame["observation.pointcloud"].shape == (2048, 3)
    assert frame["observation.pointcloud"].dtype == torch.float32
    assert frame["task"] == "pseudo-s37-000000"
    assert not (dataset_dir / ".shards").exists()


def test_every_frame_matches_the_contract(episodes):
    for episode in episodes:
        points, state, action = episode["points"], episode["state"], episode["action"]
        assert points.dtype == np.float32 and points.shape[1:] == (2048, 3)
        assert np.isfinite(points).all()
        assert points[..., 2].min() > -0.01, "object points below the table"
        for vectors in (state, action):
            assert vectors.dtype == np.float32 and vectors.shape[1] == 8
            np.testing.assert_allclose(np.linalg.norm(vectors[:, 3:7], axis=1), 1.0, atol=1e-5)
            assert set(np.unique(vectors[:, 7])) <= {0.0, 1.0}
        assert (state[:, 7] == 0).any() or (action[:, 7] == 0).any(), "a pseudo-task needs a gripper change"


def test_consecutive_poses_are_at_most_1cm_and_3deg_apart(episodes):
    for episode in episodes:
        poses = _poses(episode["state"])
        translation, rotation = pose_distance(poses[:-1], poses[1:])
        assert translation.max() <= 0.01 + 1e-5
        assert np.rad2deg(rotation.max()) <= 3.0 + 1e-3


def test_demonstrations_of_a_task_share_waypoints_in_object_frames(dataset_dir, episodes):
    tasks = {record["task"]: record for record in map(json.loads, (dataset_dir / "meta/pseudo_tasks.jsonl").read_text().splitlines())}
    scenes = [json.loads(line) for line in (dataset_dir / "meta/pseudo_demos.jsonl").read_text().splitlines()]
    assert len(scenes) == len(episodes) and len(tasks) == 2
    for scene, episode in zip(scenes, episodes, strict=True):
        assert scene["task"] == episode["task"] and scene["num_frames"] == len(episode["state"])
        poses = _poses(episode["state"])
        for waypoint in tasks[scene["task"]]["waypoints"]:
            target = np.asarray(scene["T_world_objects"][waypoint["anchor"]]) @ np.asarray(waypoint["T_anchor_ee"])
            translation, rotation = pose_distance(poses, target[None])
            closest = np.argmin(translation + rotation)
            assert translation[closest] < 1e-4 and rotation[closest] < 1e-4, f"{scene['task']}: a waypoint is never reached"
    for task in tasks:
        layouts = [np.asarray(scene["T_world_objects"]) for scene in scenes if scene["task"] == task]
        assert len(layouts) == 2
        assert not np.allclose(layouts[0], layouts[1]), "demonstrations must place the objects anew"


def _closed_runs(action: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) frames of each stretch over which the gripper is commanded closed (faults don't count)."""
    closed = np.concatenate([[False], action[:, 7] == 0, [False]])
    edges = np.flatnonzero(np.diff(closed.astype(int)))
    return [(start + 1, stop - 1) for start, stop in zip(edges[::2], edges[1::2], strict=True) if stop - 1 > start + 1]


def test_held_object_points_move_rigidly_with_the_gripper(episodes):
    """Over a closed-gripper stretch the cloud is static objects plus points fixed in the EE frame."""
    carried_runs = 0
    for episode in episodes:
        state, action, points = episode["state"], episode["action"], episode["points"].astype(np.float64)
        poses = _poses(state)
        for first, last in _closed_runs(action):
            if np.linalg.norm(poses[last, :3, 3] - poses[first, :3, 3]) < 0.05:
                continue
            ee_first = transform_points(invert(poses[first]), points[first])
            ee_last = transform_points(invert(poses[last]), points[last])
            world_distance, _ = cKDTree(points[first]).query(points[last])
            ee_distance, _ = cKDTree(ee_first).query(ee_last)
            explained = np.minimum(world_distance, ee_distance) < 0.01
            assert explained.mean() > 0.9, "points neither static nor moving with the gripper"
            carried_runs += ((ee_distance < 0.006) & (world_distance > 0.02)).mean() > 0.1
    assert carried_runs >= 3, "grasped objects must be seen moving with the gripper"


def _table(root) -> dict[str, np.ndarray]:
    frame = pq.ParquetDataset(sorted((root / "data").rglob("*.parquet"))).read().to_pandas()
    return {
        column: np.stack([np.stack(list(value)) if getattr(value, "dtype", None) == object else value for value in frame[column]])
        for column in ("observation.pointcloud", "observation.state", "action", "task_index", "episode_index")
    }


def test_same_seed_gives_the_same_dataset_also_when_interrupted_and_resumed_with_more_workers(
    tmp_path, interrupted_and_resumed
):
    """The module's dataset, interrupted after its first shard and resumed with 2 workers, is the one a single
    uninterrupted worker writes; another seed gives other data."""
    run = interrupted_and_resumed
    assert run["finished_episodes"] == 2
    assert run["plain_code"] == 2, "an interrupted output must not be overwritten silently"
    assert run["resumed_code"] == 0
    fresh = tmp_path / "fresh"
    assert _generate(fresh, *ARGUMENTS) == 0

    left, right = _table(fresh), _table(run["out"])
    for column in left:
        np.testing.assert_array_equal(left[column], right[column])
    other = tmp_path / "other_seed"
    assert _generate(other, "--num-tasks", "1", "--demos-per-task", "1", "--seed", "12") == 0
    other_seed = _table(other)
    assert not np.array_equal(other_seed["observation.state"][:10], left["observation.state"][:10])


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--num-tasks", "0"], "num_tasks must be a positive integer"),
        (["--demos-per-task", "-2"], "demos_per_task must be a positive integer"),
        (["--workers", "0"], "workers must be a positive integer"),
        (["--first-task", "-1"], "first_task must be a non-negative integer"),
        (["--objects", "pb/mug", "urdf/1234"], "unknown object id 'urdf/1234'"),
        (["--resume", "--overwrite"], "either --overwrite or --resume"),
        (["--start-max-roll-deg", "-5"], "demo.start_max_roll_deg must lie in [0, 180] degrees, got -5.0"),
    ],
)
def test_bad_arguments_fail_clearly_and_write_nothing(tmp_path, capsys, arguments, message):
    out = tmp_path / "out"
    assert _generate(out, *arguments) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_existing_output_is_never_overwritten_without_consent(tmp_path, capsys):
    out = tmp_path / "existing"
    out.mkdir()
    (out / "precious.txt").write_text("keep me")
    assert _generate(out, "--num-tasks", "1") == 2
    assert "already exists" in capsys.readouterr().err
    assert (out / "precious.txt").read_text() == "keep me"
    assert _generate(out, "--num-tasks", "1", "--resume") == 2
    assert "no resumable generation" in capsys.readouterr().err
    assert (out / "precious.txt").read_text() == "keep me"


def test_resume_refuses_changed_settings(tmp_path, capsys):
    from lerobot_instant_policy.cli.generate import build_parser, config_from_args
    from lerobot_instant_policy.pseudo_demos.generation import prepare_output

    out = tmp_path / "run"
    config = config_from_args(build_parser().parse_args(["--out", str(out), "--num-tasks", "2", "--seed", "1"]))
    prepare_output(config, overwrite=False, resume=False)
    assert _generate(out, "--num-tasks", "2", "--seed", "2", "--resume") == 2
    assert "settings differ" in capsys.readouterr().err


def test_unwritable_output_fails_clearly(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert _generate(blocker / "out", "--num-tasks", "1") == 2
    assert "cannot write" in capsys.readouterr().err
    assert blocker.read_text() == "not a directory"


def test_a_ladder_rung_with_object_groups(tmp_path):
    """``--family reach --tasks-per-object-group 2``: tasks of a group share their objects but not their motion, and
    every demonstration of a task ends at the task's pose relative to its anchor object."""
    from lerobot.datasets import LeRobotDataset

    out = tmp_path / "reach"
    assert _generate(out, "--family", "reach", "--tasks-per-object-group", "2", "--num-tasks", "2",
                     "--demos-per-task", "2", "--seed", "4", "--config", _cheap_clouds(tmp_path)) == 0
    tasks = [json.loads(line) for line in (out / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()]
    scenes = [json.loads(line) for line in (out / "meta" / "pseudo_demos.jsonl").read_text().splitlines()]
    assert [task["template"] for task in tasks] == ["reach"] * 2
    assert tasks[0]["object_ids"] == tasks[1]["object_ids"]
    assert tasks[0]["waypoints"] != tasks[1]["waypoints"]
    dataset = LeRobotDataset(REPO_ID, root=out)
    by_task = {task["task"]: task for task in tasks}
    for index, scene in enumerate(scenes):
        episode = read_episode(dataset, index)
        state = episode["state"]
        assert set(np.unique(episode["action"][:, 7]).tolist()) == {1.0}  # reach: the gripper is never closed
        (waypoint,) = by_task[scene["task"]]["waypoints"]
        T_world_anchor = np.array(scene["T_world_objects"])[waypoint["anchor"]]
        T_anchor_ee = invert(T_world_anchor) @ pose_from_pos_quat(state[-1, :3].astype(float), state[-1, 3:7].astype(float))
        np.testing.assert_allclose(T_anchor_ee, np.array(waypoint["T_anchor_ee"]), atol=2e-4)


def test_surface_clouds_from_the_command_line(tmp_path):
    """``--cloud surface``: every frame holds complete object surfaces, and a resume with rendered clouds is refused."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.cli.generate import build_parser, config_from_args

    config = config_from_args(build_parser().parse_args(["--cloud", "surface", "--num-tasks", "1"]))
    assert config.render.cloud == "surface" and config.plan()["render"]["cloud"] == "surface"
    out = tmp_path / "surface"
    assert _generate(out, "--family", "reach", "--cloud", "surface", "--num-tasks", "1", "--demos-per-task", "2") == 0
    scenes = [json.loads(line) for line in (out / "meta" / "pseudo_demos.jsonl").read_text().splitlines()]
    episode = read_episode(LeRobotDataset(REPO_ID, root=out), 0)
    # every point of the first frame is one of the objects' surface samples in its initial pose (rendered points lie
    # on the surface, but between the samples)
    task = json.loads((out / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()[0])
    samples = np.concatenate([
        transform_points(np.array(pose), load_object(object_id).surface_points)
        for object_id, pose in zip(task["object_ids"], scenes[0]["T_world_objects"], strict=True)
    ])
    distances = cKDTree(samples).query(episode["points"][0].astype(np.float64))[0]
    assert distances.max() < 1e-5
    assert scenes[0]["task"] == scenes[1]["task"]
    assert _generate(out, "--family", "reach", "--num-tasks", "1", "--demos-per-task", "2", "--resume") == 2


def test_shared_object_layout_places_every_demonstration_of_a_task_alike(tmp_path):
    """``--share-object-layout``: the demonstrations of a task start from different gripper poses in one object
    layout, which the plan records; other tasks get their own layouts."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.cli.generate import build_parser, config_from_args

    config = config_from_args(build_parser().parse_args(["--share-object-layout", "--num-tasks", "1"]))
    assert config.demo.shared_layout_fraction == 1.0 and config.plan()["demo"]["shared_layout_fraction"] == 1.0
    out = tmp_path / "shared"
    assert _generate(out, "--family", "reach", "--share-object-layout", "--num-tasks", "2",
                     "--demos-per-task", "2", "--seed", "6") == 0
    scenes = [json.loads(line) for line in (out / "meta" / "pseudo_demos.jsonl").read_text().splitlines()]
    by_task: dict[str, list[dict]] = {}
    for scene in scenes:
        by_task.setdefault(scene["task"], []).append(scene)
    first, second = by_task.values()
    for demos in (first, second):
        assert len(demos) == 2
        for demo in demos[1:]:
            assert demo["T_world_objects"] == demos[0]["T_world_objects"]
            assert demo["T_world_ee_start"] != demos[0]["T_world_ee_start"]
    assert first[0]["T_world_objects"] != second[0]["T_world_objects"]
    # the rendered scenes agree too: the first frames' clouds of one task lie on the same object surfaces
    dataset = LeRobotDataset(REPO_ID, root=out)
    clouds = [read_episode(dataset, index)["points"][0].astype(np.float64) for index in range(2)]
    assert np.median(cKDTree(clouds[0]).query(clouds[1])[0]) < 0.01


def test_first_task_writes_the_seeds_tasks_from_that_index(tmp_path):
    """``--first-task 2 --num-tasks 1`` writes task 2 of the seed: the last task of the same seed's three-task dataset
    (its record, name and demonstrations), as the pseudo-task stream draws it at index 2."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.cli.generate import build_parser, config_from_args
    from lerobot_instant_policy.pseudo_demos.generation import plan_task

    common = ("--family", "reach", "--demos-per-task", "2", "--seed", "6", "--config", _cheap_clouds(tmp_path))
    assert _generate(tmp_path / "all", "--num-tasks", "3", *common) == 0
    assert _generate(tmp_path / "third", "--first-task", "2", "--num-tasks", "1", *common) == 0
    records = {name: (tmp_path / name / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()
               for name in ("all", "third")}
    assert records["third"] == records["all"][2:]
    assert json.loads(records["third"][0])["task"] == "pseudo-s6-000002"
    whole, third = (LeRobotDataset(REPO_ID, root=tmp_path / name) for name in ("all", "third"))
    planned = plan_task(config_from_args(build_parser().parse_args(list(common))), 2)
    for demo in range(2):
        episode, expected = read_episode(third, demo), read_episode(whole, 4 + demo)
        assert episode["task"] == expected["task"] == "pseudo-s6-000002"
        np.testing.assert_array_equal(episode["state"], expected["state"])
        np.testing.assert_array_equal(episode["points"], expected["points"])
        np.testing.assert_allclose(episode["action"], planned.demos[demo].action, rtol=0, atol=1e-6)


def test_shared_layout_fraction_mixes_one_layout_and_moved_object_tasks_without_changing_the_tasks(tmp_path, capsys):
    """``--shared-layout-fraction 0.5``: some tasks keep one layout, the others move their objects between
    demonstrations, as ``meta/pseudo_tasks.jsonl`` records; the tasks themselves and the first demonstration of each
    are those of the same seed without sharing (the choice has its own random stream). A fraction outside [0, 1] or
    given with --share-object-layout is refused before anything is written."""
    runs = {}
    for name, fraction in (("mixed", "0.5"), ("moved", "0")):  # seed 8 at 0.5: task 0 moves, task 1 keeps its layout
        out = tmp_path / name
        assert _generate(out, "--family", "reach", "--shared-layout-fraction", fraction, "--num-tasks", "2",
                         "--demos-per-task", "2", "--seed", "8", "--config", _cheap_clouds(tmp_path)) == 0
        tasks = [json.loads(line) for line in (out / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()]
        scenes = [json.loads(line) for line in (out / "meta" / "pseudo_demos.jsonl").read_text().splitlines()]
        runs[name] = tasks, scenes
    tasks, scenes = runs["mixed"]
    flags = [task["shared_layout"] for task in tasks]
    assert 0 < sum(flags) < len(flags)
    for index, task in enumerate(tasks):
        first, second = scenes[2 * index: 2 * index + 2]
        assert (first["T_world_objects"] == second["T_world_objects"]) == task["shared_layout"]
    moved_tasks, moved_scenes = runs["moved"]
    assert not any(task["shared_layout"] for task in moved_tasks)
    assert [task["waypoints"] for task in moved_tasks] == [task["waypoints"] for task in tasks]
    assert [scene["T_world_objects"] for scene in moved_scenes[::2]] == [scene["T_world_objects"] for scene in scenes[::2]]
    for bad in (["--shared-layout-fraction", "1.5"], ["--shared-layout-fraction", "0.5", "--share-object-layout"]):
        capsys.readouterr()
        assert _generate(tmp_path / "bad", "--family", "reach", "--num-tasks", "1", *bad) == 2
        assert "shared-layout-fraction" in capsys.readouterr().err.replace("shared_layout_fraction", "shared-layout-fraction")
        assert not (tmp_path / "bad").exists()


def test_layout_shift_moves_the_objects_that_fraction_of_the_way_to_the_independent_draw(tmp_path, capsys):
    """``--layout-shift 0.25``: every later demonstration places each object a quarter of the way from its pose in
    the task's first demonstration towards a fresh draw: exactly a quarter of the way to where the same seed without
    the setting (the paper's independent draw) puts it where both drew the same layout (a task's second
    demonstration, unless a scene attempt was rejected in one run only: the draws after a rendered cloud differ with
    its size), and never further than a quarter of the table's placement range; the first demonstrations are unchanged. The plan records
    the setting only when it differs from the paper's (so generations written before it existed still resume); a
    shift outside [0, 1] is refused before anything is written."""
    from lerobot_instant_policy.pseudo_demos.replay import DemoConfig

    runs = {}
    for name, extra in (("shifted", ["--layout-shift", "0.25"]), ("moved", [])):
        out = tmp_path / name
        assert _generate(out, "--family", "reach", "--num-tasks", "4", "--demos-per-task", "2", "--seed", "9",
                         "--config", _cheap_clouds(tmp_path), *extra) == 0
        runs[name] = [json.loads(line) for line in (out / "meta" / "pseudo_demos.jsonl").read_text().splitlines()]

    def position_and_yaw(T):
        T = np.asarray(T)
        return T[:2, 3], np.arctan2(T[1, 0], T[0, 0])

    ranges = DemoConfig()
    reach = np.hypot(np.ptp(ranges.object_x_range), np.ptp(ranges.object_y_range)) * 0.25
    matches = checked = 0
    for index in range(0, len(runs["moved"]), 2):
        first, moved, shifted = runs["moved"][index], runs["moved"][index: index + 2], runs["shifted"][index: index + 2]
        assert shifted[0]["T_world_objects"] == first["T_world_objects"]
        for number, (drawn, demo) in enumerate(zip(moved[1:], shifted[1:])):
            checked += number == 0
            quarter = True
            for T_first, T_drawn, T_shifted in zip(first["T_world_objects"], drawn["T_world_objects"],
                                                   demo["T_world_objects"]):
                (p0, yaw0), (p1, yaw1), (p, yaw) = map(position_and_yaw, (T_first, T_drawn, T_shifted))
                assert np.linalg.norm(p - p0) <= reach + 1e-6
                turn = (yaw1 - yaw0 + np.pi) % (2 * np.pi) - np.pi
                quarter &= bool(np.allclose(p, p0 + 0.25 * (p1 - p0), atol=1e-5)  # poses recorded to 6 decimals
                                and abs((yaw - yaw0 - 0.25 * turn + np.pi) % (2 * np.pi) - np.pi) < 1e-4)
            matches += quarter and number == 0
    assert matches >= checked / 2, (matches, checked)
    from lerobot_instant_policy.cli.generate import build_parser, config_from_args

    assert "layout_shift" not in config_from_args(build_parser().parse_args([])).plan()["demo"]
    assert config_from_args(build_parser().parse_args(["--layout-shift", "0.5"])).plan()["demo"]["layout_shift"] == 0.5
    capsys.readouterr()
    assert _generate(tmp_path / "bad", "--family", "reach", "--num-tasks", "1", "--layout-shift", "1.5") == 2
    assert "demo.layout_shift must lie in [0, 1]" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_layout_angles_out_of_range_fail_clearly_and_write_nothing(tmp_path, capsys):
    config = tmp_path / "bad.json"
    config.write_text(json.dumps({"family": "reach", "demo": {"object_max_yaw_deg": 200.0}}))
    out = tmp_path / "out"
    assert _generate(out, "--config", str(config)) == 2
    assert "demo.object_max_yaw_deg must lie in [0, 180] degrees, got 200.0" in capsys.readouterr().err
    assert not out.exists()


def test_layout_angle_flags_reach_the_written_scenes(tmp_path):
    """``--object-max-yaw-deg 0 --start-max-roll-deg 0``: every recorded object pose is unturned, and the plan says
    so (a resumed run with other angles is refused by the plan check)."""
    out = tmp_path / "aligned"
    assert _generate(out, "--family", "reach", "--num-tasks", "1", "--demos-per-task", "2", "--seed", "4",
                     "--object-max-yaw-deg", "0", "--start-max-roll-deg", "0", "--config", _cheap_clouds(tmp_path)) == 0
    scenes = [json.loads(line) for line in (out / "meta" / "pseudo_demos.jsonl").read_text().splitlines()]
    for scene in scenes:
        np.testing.assert_allclose(np.asarray(scene["T_world_objects"])[:, :3, :3], np.tile(np.eye(3), (2, 1, 1)),
                                   atol=1e-6)
    from lerobot_instant_policy.cli.generate import build_parser, config_from_args

    config = config_from_args(build_parser().parse_args(["--object-max-yaw-deg", "0", "--start-max-roll-deg", "0"]))
    assert config.plan()["demo"]["object_max_yaw_deg"] == 0.0 and config.plan()["demo"]["start_max_roll_deg"] == 0.0


def test_waypoint_roll_flag_reaches_the_written_tasks(tmp_path):
    """``--waypoint-max-roll-deg 0``: every written task's gripper pose has the reference roll about its approach; the
    plan (which a resumed run must match) records the bound."""
    out = tmp_path / "unturned"
    assert _generate(out, "--family", "reach_grip", "--num-tasks", "2", "--demos-per-task", "1", "--seed", "4",
                     "--waypoint-max-roll-deg", "0", "--config", _cheap_clouds(tmp_path)) == 0
    tasks = [json.loads(line) for line in (out / "meta" / "pseudo_tasks.jsonl").read_text().splitlines()]
    assert len(tasks) == 2
    for task in tasks:
        for waypoint in task["waypoints"]:
            T_anchor_ee = np.asarray(waypoint["T_anchor_ee"])
            np.testing.assert_allclose(T_anchor_ee[:3, :3], look_rotation(T_anchor_ee[:3, 2], 0.0), atol=1e-5)
    from lerobot_instant_policy.cli.generate import build_parser, config_from_args

    assert config_from_args(build_parser().parse_args(["--waypoint-max-roll-deg", "30"])).plan()[
        "waypoint_max_roll_deg"] == 30.0


def test_splat_rendering_writes_the_pybullet_datasets_demonstrations(
    tmp_path, capsys, single_torch_thread, dataset_dir
):
    """``--renderer splat``: the same config writes the same demonstrations (states, actions, task and scene records)
    as with pybullet; only the clouds differ, each of 2048 finite points within a few mm of pybullet's. The plan
    records the renderer, so a resume with the other one is refused. The pybullet side is the module's dataset's
    first task (every task is drawn from a random stream of its own, so it is that of a one-task run)."""
    arguments = ["--num-tasks", "1", "--demos-per-task", "2", "--seed", "37"]
    splat = tmp_path / "splat"
    assert _generate(splat, *arguments, "--renderer", "splat") == 0
    module_table = _table(dataset_dir)
    first_task = module_table["task_index"] == 0
    left = {column: values[first_task] for column, values in module_table.items()}
    right = _table(splat)
    for column in ("observation.state", "action", "task_index", "episode_index"):
        np.testing.assert_array_equal(left[column], right[column])
    for name, lines in (("pseudo_tasks.jsonl", 1), ("pseudo_demos.jsonl", 2)):
        pybullet_lines = (dataset_dir / "meta" / name).read_text().splitlines(keepends=True)[:lines]
        assert (splat / "meta" / name).read_text() == "".join(pybullet_lines)
    clouds = right["observation.pointcloud"]
    assert clouds.shape == left["observation.pointcloud"].shape and clouds.shape[1:] == (2048, 3)
    assert clouds.dtype == np.float32 and np.isfinite(clouds).all()
    assert not np.array_equal(clouds, left["observation.pointcloud"])
    for frame in range(0, len(clouds), 25):
        splat_to_pybullet = cKDTree(left["observation.pointcloud"][frame]).query(clouds[frame])[0].mean()
        assert splat_to_pybullet < 0.006, f"frame {frame}: {splat_to_pybullet * 1e3:.1f} mm from pybullet's cloud"

    from lerobot_instant_policy.cli.generate import build_parser, config_from_args
    from lerobot_instant_policy.pseudo_demos.generation import prepare_output

    interrupted = tmp_path / "interrupted"
    config = config_from_args(build_parser().parse_args(["--out", str(interrupted), "--repo-id", REPO_ID, *arguments]))
    assert "renderer" not in config.plan()["render"], "plans written before the choice existed must still match"
    prepare_output(config, overwrite=False, resume=False)
    assert _generate(interrupted, *arguments, "--renderer", "splat", "--resume") == 2
    assert "settings differ from the interrupted run in ['render']" in capsys.readouterr().err


def test_an_unknown_renderer_is_refused_by_name(tmp_path, capsys):
    config = tmp_path / "blender.json"
    config.write_text(json.dumps({"render": {"renderer": "blender"}}))
    out = tmp_path / "out"
    assert generate_main(["--config", str(config), "--out", str(out), "--no-progress"]) == 2
    assert "render.renderer must be one of ['pybullet', 'splat'], got 'blender'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _generate(out, "--renderer", "blender")
    assert "invalid choice: 'blender'" in capsys.readouterr().err
    config.write_text(json.dumps({"render": {"renderer": "splat", "cloud": "surface"}}))
    assert generate_main(["--config", str(config), "--out", str(out), "--no-progress"]) == 2
    assert "render.renderer 'splat' renders the cameras' views" in capsys.readouterr().err
    assert not out.exists()
