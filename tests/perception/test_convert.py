"""``lerobot-ip-convert`` on datasets recorded in ``bullet_tabletop``'s RGB-D mode, and its clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lerobot_instant_policy.cli.convert import main
from lerobot_instant_policy.cli.dry_run import main as dry_run_main
from lerobot_instant_policy.data.demonstrations import DemonstrationError, load_demonstrations
from lerobot_instant_policy.perception.convert import ConversionError, ConvertSettings, convert
from lerobot_instant_policy.sim.recording import JOINT_POSITIONS_KEY, depth_key, record
from lerobot_instant_policy.sim.robot import JOINT_NAMES, low_poly_panda_urdf

TASK = "push_button"
ROBOT = dict(urdf=low_poly_panda_urdf(), joint_key=JOINT_POSITIONS_KEY, joint_names=list(JOINT_NAMES))


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Two scripted push_button demonstrations (seeds 3, 4) recorded as raw RGB-D and as segmented clouds."""
    root = tmp_path_factory.mktemp("recordings")
    record(TASK, 2, root / "rgbd", "local/rgbd", 3, obs_type="rgbd")
    record(TASK, 2, root / "segmented", "local/segmented", 3)
    return root


def test_converted_rgbd_demonstration_matches_the_segmented_one(recordings, tmp_path):
    out = tmp_path / "converted"
    summary = convert(ConvertSettings(recordings / "rgbd", "local/rgbd", out, "local/converted", action_source="dataset", **ROBOT))
    assert summary["episodes"] == 2 and (out / "meta" / "camera_calibration.json").is_file()
    (converted,) = load_demonstrations("local/converted", out, TASK, 1)
    (segmented,) = load_demonstrations("local/segmented", recordings / "segmented", TASK, 1)
    assert converted.points_world.shape == segmented.points_world.shape
    assert converted.state == pytest.approx(segmented.state, abs=1e-6)
    assert converted.action == pytest.approx(segmented.action, abs=1e-6)
    for frame in (0, len(converted.state) // 2, -1):
        distance, _ = cKDTree(segmented.points_world[frame]).query(converted.points_world[frame])
        assert np.percentile(distance, 99) < 0.01, frame
    png = tmp_path / "dry_run.png"
    assert dry_run_main(["--demos", str(out), "--repo-id", "local/converted", "--episode", "1", "--out", str(png)]) == 0
    assert png.stat().st_size > 10_000
    assert dry_run_main(["--demos", str(out), "--repo-id", "local/converted", "--episode", "5"]) == 2


def test_forward_kinematics_and_next_state_actions(recordings, tmp_path):
    out = tmp_path / "fk"
    settings = ConvertSettings(
        recordings / "rgbd", "local/rgbd", out, "local/fk", num_points=256, ee_link="panda_grasptarget",
        gripper_key="observation.state", gripper_index=7, **ROBOT,
    )
    convert(settings)
    (by_fk,) = load_demonstrations("local/fk", out, TASK, 1)
    (cartesian,) = load_demonstrations("local/segmented", recordings / "segmented", TASK, 1)
    assert by_fk.points_world.shape[1] == 256
    assert by_fk.state[:, :3] == pytest.approx(cartesian.state[:, :3], abs=2e-4)
    assert np.abs(np.abs(np.sum(by_fk.state[:, 3:7] * cartesian.state[:, 3:7], axis=1)) - 1).max() < 1e-4
    assert (by_fk.state[:, 3:7][:, 3] >= 0).all() and by_fk.state[:, 7] == pytest.approx(cartesian.state[:, 7])
    assert by_fk.action[:-1] == pytest.approx(by_fk.state[1:]) and by_fk.action[-1] == pytest.approx(by_fk.state[-1])


def test_cli_with_a_calibration_file_and_the_gripper_box(recordings, tmp_path, capsys):
    info = json.loads((recordings / "rgbd" / "meta" / "info.json").read_text())
    cameras = []
    for index in range(3):
        entry = info["features"][depth_key(index)]["info"]["camera_calibration"]
        cameras.append({**entry, "depth_key": depth_key(index), "depth_unit": "m"})
    calibration = tmp_path / "calibration.json"
    calibration.write_text(json.dumps({"cameras": cameras}))
    args = ["--input", str(recordings / "rgbd"), "--input-repo-id", "local/rgbd", "--out", str(tmp_path / "cli"),
            "--repo-id", "local/cli", "--calibration", str(calibration), "--num-points", "128"]
    assert main(args) == 0
    assert "converted 2 episodes" in capsys.readouterr().out
    (demo,) = load_demonstrations("local/cli", tmp_path / "cli", TASK, 1)
    assert demo.points_world.shape[1:] == (128, 3)
    assert main(args) == 2 and "already exists" in capsys.readouterr().err


def test_raw_rgbd_dataset_is_not_a_demonstration_dataset(recordings):
    with pytest.raises(DemonstrationError, match="missing key 'observation.pointcloud'"):
        load_demonstrations("local/rgbd", recordings / "rgbd", TASK, 1)


@pytest.mark.parametrize(
    "overrides, error, message",
    [
        (dict(state_key="observation.velocity"), ConversionError, "lacks \\['observation.velocity'\\]"),
        (dict(state_key=JOINT_POSITIONS_KEY), ConversionError, "Cartesian state must be \\(8,\\)"),
        (dict(ee_link="panda_grasptarget", urdf=None, joint_key=None), ConversionError, "needs --urdf"),
        (dict(action_source="delta"), ConversionError, "action_source"),
    ],
)
def test_bad_conversion_settings_raise(recordings, tmp_path, overrides, error, message):
    with pytest.raises(error, match=message):
        convert(ConvertSettings(recordings / "rgbd", "local/rgbd", tmp_path / "x", "local/x", **overrides))


def test_cli_errors_are_one_line(recordings, tmp_path, capsys):
    base = ["--input-repo-id", "local/x", "--out", str(tmp_path / "out"), "--repo-id", "local/out"]
    assert main(["--input", str(tmp_path / "nothing"), *base]) == 2
    assert "no LeRobot dataset" in capsys.readouterr().err
    assert main(["--input", str(recordings / "segmented"), *base]) == 2  # a cloud dataset has no depth cameras
    assert "carry no 'camera_calibration'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as refused:  # argparse's own refusal of a workspace corner that is not x,y,z
        main(["--input", str(recordings / "rgbd"), *base, "--workspace-low", "0.1,0.2"])
    assert refused.value.code == 2 and "expected x,y,z, got '0.1,0.2'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_depth_stored_in_millimetres_but_labelled_metres_raises(tmp_path):
    """A dataset whose depth feature says metres but holds millimetres: a clear error, no cloud, no dataset."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.perception.depth import DepthUnitError

    source = tmp_path / "mislabelled"
    entry = {"width": 32, "height": 24, "fx": 30.0, "fy": 30.0, "cx": 15.5, "cy": 11.5, "T_world_camera": np.eye(4).tolist()}
    features = {
        "observation.images.top_depth": {
            "dtype": "image", "shape": (24, 32, 1), "names": ["height", "width", "channels"],
            "info": {"is_depth_map": True, "depth_unit": "m", "camera_calibration": entry},
        },
        "observation.state": {"dtype": "float32", "shape": (8,), "names": None},
    }
    dataset = LeRobotDataset.create("local/mm", fps=10, features=features, root=source, use_videos=False)
    dataset.add_frame({
        "observation.images.top_depth": np.full((24, 32, 1), 800, dtype=np.uint16),
        "observation.state": np.array([0.5, 0, 0.3, 1, 0, 0, 0, 1], dtype=np.float32),
        "task": TASK,
    })
    dataset.save_episode()
    dataset.finalize()
    with pytest.raises(DepthUnitError, match="millimetres"):
        convert(ConvertSettings(source, "local/mm", tmp_path / "out", "local/out"))
    assert not (tmp_path / "out" / "meta" / "info.json").exists()


def test_eval_suite_env_args_and_rgbd_demo_roots(tmp_path):
    from lerobot_instant_policy.evaluation.suite import demo_root
    from lerobot_instant_policy.evaluation.suite_command import parse_env_arg

    assert parse_env_arg("depth_noise_std=0.002") == "--env.depth_noise_std=0.002"
    assert demo_root(tmp_path, TASK, 2, 0, "rgbd").name == f"{TASK}-n2-s0-rgbd"
    assert demo_root(tmp_path, TASK, 2, 0).name == f"{TASK}-n2-s0"


@pytest.mark.slow
def test_demo_replay_succeeds_on_processed_raw_depth_through_lerobot_eval(tmp_path):
    """The real-robot path end to end: record raw depth, convert, lerobot-eval with --env.obs_type=rgbd."""
    from lerobot_instant_policy.cli.eval_suite import main as eval_suite_main

    args = ["--policy", "demo_replay", "--obs-type", "rgbd", "--tasks", TASK, "--episodes", "2", "--demo-sets", "1",
            "--out", str(tmp_path)]
    assert eval_suite_main(args) == 0
    table = json.loads((tmp_path / "success_table_demo_replay.json").read_text())
    assert (tmp_path / "demos" / f"{TASK}-n2-s0-rgbd" / "meta" / "camera_calibration.json").is_file()
    (row,) = table["rows"]
    assert row["task"] == TASK and row["episodes"] == 2 and row["success_rate"] >= 0.5
