"""LeRobot's MetaWorld env with the data contract (issue 31): the action mapping, the segmented clouds, rendering
only where a policy looks, expert demonstrations, one task end to end through lerobot-eval, and the setup errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "osmesa")  # as make eval-metaworld sets it, before anything imports mujoco

from lerobot_instant_policy.sim.metaworld import dependencies  # noqa: E402
from lerobot_instant_policy.sim.metaworld.actions import ee_target, metaworld_action  # noqa: E402
from lerobot_instant_policy.sim.metaworld.configuration_metaworld import resolve_tasks  # noqa: E402

REPO = Path(__file__).resolve().parents[3]
CHECKPOINT = REPO / "lerobot_instant_policy" / "assets" / "checkpoints" / "instant_policy"


def _metaworld_or_skip():
    """Skip (with the one-line reason) where the metaworld extra or the GL library cannot be had."""
    try:
        dependencies.import_metaworld()
    except dependencies.MetaworldSetupError as error:
        pytest.skip(str(error))


@pytest.fixture(scope="module")
def pick_place_env():
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv

    env = MetaworldPointCloudEnv("pick-place-v3")
    yield env
    env.close()


# ------------------------------------------------------------------------------------------------ action mapping
def test_target_within_one_step_maps_to_its_displacement_and_gripper():
    ee = np.array([0.0, 0.6, 0.15])
    target = np.array([0.004, 0.593, 0.16, 0.0, 1.0, 0.0, 0.0, 1.0])
    action = metaworld_action(target, ee, 0.01)
    np.testing.assert_allclose(action, [0.4, -0.7, 1.0, -1.0], atol=1e-6)  # gripper open -> MetaWorld's -1
    target[7] = 0.0
    assert metaworld_action(target, ee, 0.01)[3] == 1.0  # closed -> +1 (MetaWorld closes on +1)


def test_far_target_is_clipped_to_metaworld_top_speed_and_quaternion_ignored():
    ee = np.array([0.0, 0.6, 0.15])
    far = np.array([0.3, 0.6, -0.2, 0.0, 0.0, 0.0, 1.0, 1.0])
    turned = far.copy()
    turned[3:7] = [0.0, 0.7071068, 0.0, 0.7071068]
    np.testing.assert_allclose(metaworld_action(far, ee, 0.01), [1.0, 0.0, -1.0, -1.0])
    np.testing.assert_array_equal(metaworld_action(far, ee, 0.01), metaworld_action(turned, ee, 0.01))


def test_expert_action_round_trips_through_the_contract():
    state = np.array([0.01, 0.62, 0.12, 0.0, 0.7071068, 0.0, 0.7071068, 1.0], dtype=np.float32)
    for expert_action in ([0.3, -1.0, 0.25, 1.0], [-0.5, 0.2, 0.0, -1.0], [2.0, -3.0, 0.1, 0.6]):
        target = ee_target(np.array(expert_action), state, 0.01)
        assert target.shape == (8,) and target.dtype == np.float32
        np.testing.assert_array_equal(target[3:7], state[3:7])
        mapped = metaworld_action(target, state[:3], 0.01)
        np.testing.assert_allclose(mapped[:3], np.clip(expert_action[:3], -1, 1), atol=1e-4)
        assert mapped[3] == np.sign(expert_action[3])


def test_expert_not_gripping_stays_open():
    """MetaWorld's experts command 0 for "not gripping": that must open, not close, the gripper."""
    state = np.array([0.0, 0.6, 0.15, 0.0, 0.7071068, 0.0, 0.7071068, 1.0], dtype=np.float32)
    assert ee_target(np.array([0.1, 0.0, -0.2, 0.0]), state, 0.01)[7] == 1.0


@pytest.mark.parametrize("bad", [np.zeros(4), np.full(8, np.nan)])
def test_bad_targets_are_refused(bad):
    with pytest.raises(ValueError, match=r"finite \(8,\) vector"):
        metaworld_action(bad, np.zeros(3), 0.01)


# ------------------------------------------------------------------------------------------------ setup errors
def test_missing_extra_is_one_clear_line(monkeypatch):
    import importlib

    real_import = importlib.import_module

    def without_metaworld(name, *args, **kwargs):
        if name == "metaworld":
            raise ImportError("No module named 'metaworld'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(dependencies, "check_mujoco_version", lambda: None)
    monkeypatch.setattr(dependencies, "check_gl_library", lambda: None)
    monkeypatch.setattr(dependencies.importlib, "import_module", without_metaworld)
    with pytest.raises(dependencies.MetaworldSetupError, match=r"metaworld extra .*pip install -e '\.\[metaworld\]'"):
        dependencies.import_metaworld()


def test_mujoco_that_breaks_metaworld_reset_is_refused(monkeypatch):
    monkeypatch.setattr(dependencies.importlib.metadata, "version", lambda name: "4.0.0")
    with pytest.raises(dependencies.MetaworldSetupError, match=r"mujoco 4\.0\.0 breaks .*mujoco<3\.4"):
        dependencies.check_mujoco_version()


def test_missing_gl_library_names_the_package(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    monkeypatch.setattr(dependencies.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(dependencies.MetaworldSetupError, match="apt-get install libosmesa6"):
        dependencies.check_gl_library()


def test_without_the_gl_library_rendering_tests_skip_with_the_one_line_reason_and_the_rest_run(tmp_path):
    """Where the OSMesa library is missing (hidden here in a child pytest), a rendering test is skipped and pytest's
    summary names the package to install, while a test of the suite protocol (lerobot-eval replaced by a stand-in)
    still runs and passes: the GL check happens where rendering does."""
    runner = tmp_path / "run.py"
    runner.write_text(
        "import ctypes.util, sys\n"
        "import pytest\n"
        "found = ctypes.util.find_library\n"
        "ctypes.util.find_library = lambda name: None if name == 'OSMesa' else found(name)\n"
        f"sys.exit(pytest.main([{str(Path(__file__))!r}, '-q', '-rs', '-p', 'no:cacheprovider', '-k', "
        "'cloud_is_rendered_on_the_steps or resume_keeps_the_finished_cells']))\n"
    )
    completed = subprocess.run([sys.executable, str(runner)], capture_output=True, text=True, cwd=REPO,
                               env={**os.environ, "MUJOCO_GL": "osmesa"})
    assert completed.returncode == 0, completed.stdout[-3000:]
    assert "1 passed, 1 skipped" in completed.stdout
    assert "SKIPPED" in completed.stdout and "apt-get install libosmesa6" in completed.stdout


def test_base_install_registers_the_env_without_metaworld():
    """make demo's path: importing the plugin registers metaworld_pointcloud and imports neither MetaWorld nor
    MuJoCo."""
    code = ("import sys, lerobot_instant_policy\nfrom lerobot.envs.configs import EnvConfig\n"
            "config = EnvConfig.get_choice_class('metaworld_pointcloud')(task='mt10')\n"
            "assert config.features['pointcloud'].shape == (2048, 3), config.features\n"
            "print(sorted(name for name in ('metaworld', 'mujoco') if name in sys.modules))")
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True)
    assert completed.stdout.strip().splitlines()[-1] == "[]"


def test_task_groups_resolve_without_metaworld_or_gl():
    """Naming tasks imports neither MetaWorld nor MuJoCo (so no GL library is needed to plan an evaluation): MT10,
    MT50, ML45's split and LeRobot's difficulty groups by name, names with LeRobot's prefix, unknown names refused."""
    code = (
        "import sys; from lerobot_instant_policy.sim.metaworld.configuration_metaworld import resolve_tasks; "
        "groups = {g: resolve_tasks(g) for g in ('mt10', 'mt50', 'ml45_train', 'ml45_test', 'easy', 'very_hard')}; "
        "assert 'mujoco' not in sys.modules and 'metaworld' not in sys.modules, sorted(sys.modules); "
        "print(repr(groups))"
    )
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                               env={**os.environ, "MUJOCO_GL": "osmesa"})
    groups = eval(completed.stdout)  # noqa: S307 - our own repr of lists of strings
    assert len(groups["mt50"]) == 50 and len(set(groups["mt50"])) == 50
    assert groups["ml45_test"] == ["bin-picking-v3", "box-close-v3", "hand-insert-v3", "door-lock-v3", "door-unlock-v3"]
    assert len(groups["ml45_train"]) == 45 and not set(groups["ml45_train"]) & set(groups["ml45_test"])
    assert set(groups["mt10"]) < set(groups["mt50"]) and "stick-pull-v3" in groups["very_hard"]

    assert resolve_tasks("metaworld-reach-v3,push-v3,reach-v3") == ["reach-v3", "push-v3"]
    with pytest.raises(ValueError, match="unknown MetaWorld task 'pick-v9'.*ml45_test"):
        resolve_tasks("pick-v9")


def test_written_out_groups_are_metaworlds_own():
    """MT10 and ML45's held-out tasks, written out so that naming them needs no MetaWorld import, are MetaWorld's own
    (read here in a process that imports MetaWorld with rendering disabled: no GL library needed)."""
    from lerobot_instant_policy.sim.metaworld.configuration_metaworld import ML45_TEST_TASKS, MT10_TASKS

    code = ("import metaworld.env_dict as d; print(repr((list(d.MT10_V3), list(d.ML45_V3['test']), "
            "list(d.ML45_V3['train']), list(d.ALL_V3_ENVIRONMENTS))))")
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               env={**os.environ, "MUJOCO_GL": "disable"})
    if completed.returncode != 0 and "No module named 'metaworld'" in completed.stderr:
        pytest.skip("the metaworld extra is not installed")
    assert completed.returncode == 0, completed.stderr[-2000:]
    mt10, ml45_test, ml45_train, all_tasks = eval(completed.stdout)  # noqa: S307
    assert (list(MT10_TASKS), list(ML45_TEST_TASKS)) == (mt10, ml45_test)
    from lerobot_instant_policy.sim.metaworld.configuration_metaworld import task_groups

    assert sorted(task_groups()["mt50"]) == sorted(all_tasks) and sorted(task_groups()["ml45_train"]) == sorted(ml45_train)


# ------------------------------------------------------------------------------------------------ observations
def test_cloud_holds_the_task_objects_and_goal_marker_only(pick_place_env):
    """Every kept point lies on the puck or on the goal marker: no robot, table, wall or floor point survives,
    although the cameras see all of them."""
    env = pick_place_env
    observation, _ = env.reset(seed=5)
    world = env.metaworld_env
    puck, goal = world._get_pos_objects(), world._target_pos
    depths, keeps = env.cameras.render(world.data)
    seen = sum(int(np.count_nonzero(depth < 3.0)) for depth in depths)
    kept = sum(int(keep.sum()) for keep in keeps)
    assert kept < 0.05 * seen  # the robot and the scenery fill the images; they are dropped
    points = env.cameras.points(world.data)
    on_puck = np.linalg.norm(points - puck, axis=1) < 0.035
    on_goal = np.linalg.norm(points - goal, axis=1) < 0.025
    assert on_puck.sum() > 100 and on_goal.sum() > 20
    assert np.all(on_puck | on_goal), points[~(on_puck | on_goal)][:5]
    cloud = observation["pointcloud"]
    assert cloud.shape == (2048, 3) and cloud.dtype == np.float32


EVERY_TASK = resolve_tasks("mt50")


@pytest.mark.parametrize("task", EVERY_TASK)
def test_every_task_resets_renders_its_objects_and_not_the_robot_or_table_and_steps(task):
    """Each of MetaWorld's 50 v3 tasks through the env: the scenery found from the model (not a list of names)
    matches MetaWorld's own names for the robot, table, retaining wall and floor (the oracle here); the cloud holds
    points at every object MetaWorld reports and none below the table top; a step moves the EE."""
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.env import CameraSettings, MetaworldPointCloudEnv

    env = MetaworldPointCloudEnv(task, cameras=CameraSettings(resolution=160))
    try:
        observation, _ = env.reset(seed=3)
        world = env.metaworld_env
        model = world.model
        names = [name for name in ("base", "mocap", "tablelink", "RetainingWall") if _has_body(model, name)]
        not_task = {model.body(name).id for name in names} | {0}
        scenery_or_robot = np.isin(model.body_rootid[model.geom_bodyid], list(not_task))
        assert not env.cameras.keep_geoms[scenery_or_robot].any() and env.cameras.keep_geoms.any()
        cloud = observation["pointcloud"]
        assert cloud.shape == (2048, 3) and cloud.dtype == np.float32 and np.isfinite(cloud).all()
        for position in np.asarray(world._get_pos_objects()).reshape(-1, 3):
            assert np.linalg.norm(cloud - position, axis=1).min() < 0.07, position
        assert cloud[:, 2].min() > -0.01  # nothing of the table's body, its legs or the floor
        target = observation["agent_pos"].copy()
        target[2] += 0.01
        for _ in range(3):  # the hand follows MetaWorld's mocap target over a few steps
            stepped, *_ = env.step(target)
        assert stepped["agent_pos"][2] > observation["agent_pos"][2] + 0.001
    finally:
        env.close()


@pytest.mark.parametrize("task", resolve_tasks("mt10"))
def test_the_first_cloud_and_state_show_the_scene_the_first_step_acts_on(task):
    """MetaWorld's reset leaves some bodies' poses at an earlier draw of the layout (the env's ``_settled_reset_state``):
    with the hand holding still for one step nothing moves, so the reset's cloud must lie where the next step's lies
    (every point within 1 cm of the other cloud, at a few seeds), and the reset's state vector must show the objects
    and the goal where the next one does."""
    _metaworld_or_skip()
    from scipy.spatial import cKDTree

    from lerobot_instant_policy.sim.metaworld.env import CameraSettings, MetaworldPointCloudEnv

    env = MetaworldPointCloudEnv(task, cameras=CameraSettings(resolution=160))
    try:
        for seed in (1, 2):
            first, _ = env.reset(seed=seed)
            held, *_ = env.step(first["agent_pos"])
            gaps, _ = cKDTree(held["pointcloud"]).query(first["pointcloud"])
            assert np.quantile(gaps, 0.99) < 0.01, (seed, float(gaps.max()))
            np.testing.assert_allclose(first["environment_state"][4:18], held["environment_state"][4:18], atol=0.01)
            np.testing.assert_allclose(first["environment_state"][36:], held["environment_state"][36:], atol=1e-6)
    finally:
        env.close()


def _has_body(model, name: str) -> bool:
    import mujoco

    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) >= 0


def test_scenery_needs_a_metaworld_model(tmp_path):
    """A model without MetaWorld's scene file or without a robot welded to a mocap body is refused by name."""
    _metaworld_or_skip()
    import mujoco

    from lerobot_instant_policy.sim.metaworld.scenery import robot_root_bodies, scene_body_names

    xml = tmp_path / "plain.xml"
    xml.write_text("<mujoco><worldbody><body name='box'><geom size='0.1'/></body></worldbody></mujoco>")
    with pytest.raises(ValueError, match="no MetaWorld scene file"):
        scene_body_names(xml)
    with pytest.raises(ValueError, match="no weld joins a mocap body"):
        robot_root_bodies(mujoco.MjModel.from_xml_path(str(xml)))


def test_state_is_the_contract_ee_pose(pick_place_env):
    from scipy.spatial.transform import Rotation

    env = pick_place_env
    observation, _ = env.reset(seed=5)
    state = observation["agent_pos"]
    np.testing.assert_allclose(state[:3], env.metaworld_env.tcp_center, atol=1e-6)
    axes = Rotation.from_quat(state[3:7]).as_matrix()
    assert axes[2, 2] < -0.99  # z, the approach axis, points down
    fingers = env.metaworld_env.data.site("leftEndEffector").xpos - env.metaworld_env.data.site("rightEndEffector").xpos
    assert abs(np.dot(axes[:, 1], fingers / np.linalg.norm(fingers))) > 0.99  # y along the finger opening
    assert state[7] == 1.0


def test_env_moves_the_ee_to_the_target_and_grips(pick_place_env):
    env = pick_place_env
    observation, _ = env.reset(seed=5)
    target = observation["agent_pos"].copy()
    target[:3] += [0.005, -0.004, 0.003]
    for _ in range(3):
        observation, _, _, _, info = env.step(target)
    np.testing.assert_allclose(observation["agent_pos"][:3], target[:3], atol=3e-3)
    target[7] = 0.0
    observation, _, _, _, info = env.step(target)
    assert info["metaworld_action"][3] == 1.0 and observation["agent_pos"][7] == 0.0


def test_cloud_is_rendered_on_the_steps_instant_policy_reads():
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv

    env = MetaworldPointCloudEnv("reach-v3", pointcloud_every=8)
    try:
        observation, _ = env.reset(seed=0)
        rendered, clouds = [], [observation["pointcloud"]]
        for step in range(24):
            action = observation["agent_pos"].copy()
            action[0] += 0.01
            action[7] = 0.0 if step >= 12 else 1.0  # the gripper closes at step 12
            observation, _, _, _, info = env.step(action)
            rendered.append(info["pointcloud_rendered"])
            clouds.append(observation["pointcloud"])
    finally:
        env.close()
    assert [step for step, flag in enumerate(rendered) if flag] == [7, 12, 20]
    np.testing.assert_array_equal(clouds[1], clouds[0])  # repeated between renderings


def test_a_rendering_that_sees_nothing_keeps_the_last_cloud_and_a_reset_that_sees_nothing_raises(monkeypatch):
    """Every object hidden mid-episode (the hand over them, a puck sunk into its hole) leaves the policy its last
    view instead of ending the evaluation; at reset there is no view to keep."""
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.cameras import EmptyCloudError
    from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv

    env = MetaworldPointCloudEnv("reach-v3", pointcloud_every=1, render_size=64)
    try:
        observation, _ = env.reset(seed=0)
        seen = observation["pointcloud"]
        action = observation["agent_pos"].copy()
        action[0] += 0.01
        with monkeypatch.context() as patch:
            patch.setattr(env.cameras, "points", lambda data: np.zeros((0, 3), dtype=np.float32))
            observation, _, _, _, info = env.step(action)
            assert not info["pointcloud_rendered"]
            np.testing.assert_array_equal(observation["pointcloud"], seen)
            with pytest.raises(EmptyCloudError, match="sees a task object"):
                env.reset(seed=1)
        observation, _ = env.reset(seed=0)
        observation, _, _, _, info = env.step(action)
        assert info["pointcloud_rendered"] and len(observation["pointcloud"]) == env.num_points
    finally:
        env.close()


def test_render_size_sets_the_video_frames_and_changes_no_observation():
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv

    observations, frames = {}, {}
    for size in (64, 480):
        env = MetaworldPointCloudEnv("drawer-open-v3", pointcloud_every=4, render_size=size)
        try:
            observation, _ = env.reset(seed=3)
            steps = [observation]
            for _ in range(6):
                action = observation["agent_pos"].copy()
                action[2] += 0.02
                observation, *_ = env.step(action)
                steps.append(observation)
            frames[size] = env.render()
        finally:
            env.close()
        observations[size] = steps
    assert frames[64].shape == (64, 64, 3) and frames[480].shape == (480, 480, 3)
    assert frames[64].std() > 0  # a drawn scene, not a blank frame
    for small, large in zip(observations[64], observations[480]):
        for key in ("pointcloud", "agent_pos", "environment_state"):
            np.testing.assert_array_equal(small[key], large[key])
    with pytest.raises(ValueError, match="render_size must be positive"):
        MetaworldPointCloudEnv("drawer-open-v3", render_size=0)


def test_expert_solves_its_task_through_the_contract():
    """MetaWorld's scripted expert, acting only through EE targets and the env's action mapping, succeeds."""
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv
    from lerobot_instant_policy.sim.metaworld.expert import expert_target, scripted_policy

    env = MetaworldPointCloudEnv("pick-place-v3", pointcloud_every=500)
    policy = scripted_policy("pick-place-v3")
    try:
        observation, _ = env.reset(seed=1000)
        for _ in range(200):
            action = expert_target(policy, observation["environment_state"], observation["agent_pos"], 0.01)
            observation, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()
    assert info["is_success"]


# MetaWorld's experts for these tasks grip with a partial effort (0.6 or 0.1) that the data contract's binary gripper
# turns into a full close, and then fail: on seeds 0-2 of MetaWorld's MT1 tasks, within 500 steps, the raw expert
# solved assembly 3/3, basketball 2/3, peg-unplug-side 3/3 and pick-out-of-hole 3/3, the same expert with its grip
# made binary 0/3 on each. The other 46 tasks' experts record through the contract.
BINARY_GRIP_FAILURES = {"assembly-v3", "basketball-v3", "peg-unplug-side-v3", "pick-out-of-hole-v3"}


@pytest.mark.slow
@pytest.mark.parametrize("task", [pytest.param(task, marks=pytest.mark.xfail(
    task in BINARY_GRIP_FAILURES, reason="the expert needs a partial grip the contract's binary gripper lacks",
    strict=True)) for task in EVERY_TASK])
def test_every_tasks_expert_demonstration_records(task, tmp_path):
    """MetaWorld's scripted expert of each task, acting through the data contract within MetaWorld's 500 steps,
    records a successful demonstration (two seeds tried)."""
    _metaworld_or_skip()
    from lerobot_instant_policy.sim.metaworld.recording import record_expert_demos

    summary = record_expert_demos(task, 1, tmp_path / task, f"local/{task}", 0, episode_length=500, max_attempts=2)
    assert summary["episodes"] == 1


# ------------------------------------------------------------------------------------------------ end to end
def test_expert_demonstrations_then_lerobot_eval_end_to_end(tmp_path):
    """2 expert demonstrations recorded by lerobot-ip-record-demos, then the shipped instant_policy reads them in
    2 evaluation episodes of lerobot-eval (with videos)."""
    _metaworld_or_skip()
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.cli.record_demos import main as record_demos
    from lerobot_instant_policy.data.demonstrations import load_demonstrations

    demos = tmp_path / "demos"
    assert record_demos(["--env", "metaworld", "--task", "reach-v3", "--episodes", "2", "--out", str(demos),
                         "--repo-id", "local/reach-v3", "--seed", "0"]) == 0
    dataset = LeRobotDataset("local/reach-v3", root=demos)
    assert dataset.meta.total_episodes == 2 and list(dataset.meta.tasks.index) == ["reach-v3"]
    demonstrations = load_demonstrations("local/reach-v3", demos, "reach-v3", 2)
    for demo in demonstrations:
        assert demo.points_world.shape[1:] == (2048, 3)
        assert np.abs(demo.action[:, :3] - demo.state[:, :3]).max() <= 0.01 + 1e-5  # one MetaWorld step per frame

    output_dir = tmp_path / "eval"
    command = [str(Path(sys.executable).with_name("lerobot-eval")), "--env.type=metaworld_pointcloud",
               "--env.task=reach-v3", "--env.episode_length=40", "--env.pointcloud_every=8",
               f"--policy.path={CHECKPOINT}", "--policy.demo_repo_id=local/reach-v3", f"--policy.demo_root={demos}",
               "--policy.num_demos=2", "--eval.n_episodes=2", "--eval.batch_size=2", "--eval.use_async_envs=false",
               "--seed=1000",
               f"--output_dir={output_dir}", "--policy.device=cpu"]
    completed = subprocess.run(command, capture_output=True, text=True, cwd=REPO,
                               env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert completed.returncode == 0, completed.stderr[-3000:]
    per_task = json.loads((output_dir / "eval_info.json").read_text())["per_task"]
    assert [entry["task_group"] for entry in per_task] == ["reach-v3"]
    assert len(per_task[0]["metrics"]["successes"]) == 2
    assert len(list((output_dir / "videos").rglob("*.mp4"))) == 2


# ------------------------------------------------------------------------------------------------ suite protocol
def test_swap_control_reads_another_kind_of_tasks_expert_relabelled(monkeypatch, tmp_path):
    """With --swap each task's lerobot-eval reads another task's expert demonstrations, recorded on the set's seeds
    and labelled with the task evaluated (reach and push are of one kind, so each reads the other; on MT10 every task
    reads one of another kind); the runs go to runs/<policy>-swap, apart from the own-demonstration runs."""
    from lerobot_instant_policy.evaluation import metaworld_suite, suite
    from lerobot_instant_policy.evaluation.suite import swap_sources
    from lerobot_instant_policy.sim.metaworld import recording
    from lerobot_instant_policy.sim.metaworld.configuration_metaworld import MT10_TASKS

    recorded, commands = [], []

    def fake_record(task, episodes, out, repo_id, seed, **kwargs):
        recorded.append((task, out.name, repo_id, seed, kwargs["label"]))
        (out / "data").mkdir(parents=True)
        (out / "data" / "file.parquet").write_text(f"{task} {seed}")

    monkeypatch.setattr(recording, "record_expert_demos", fake_record)
    def fake_lerobot_eval(command, runs_dir, task, demo_set):
        commands.append(command)
        (runs_dir / task / f"set-{demo_set}").mkdir(parents=True)
        return runs_dir / task / f"set-{demo_set}"

    monkeypatch.setattr(suite, "run_lerobot_eval", fake_lerobot_eval)
    settings = suite.SuiteSettings(env_type="metaworld_pointcloud", policy="instant_policy", policy_path="ckpt",
                                   out=tmp_path, demo_sets=2, swap=True, env_args=("--env.render_size=64",))
    runs = suite.run_suite(settings, ["reach-v3", "push-v3"], report=lambda line: None)

    assert recorded == [("push-v3", "reach-v3-n2-s0-from-push-v3", "local/reach-v3", 0, "reach-v3"),
                        ("push-v3", "reach-v3-n2-s100-from-push-v3", "local/reach-v3", 100, "reach-v3"),
                        ("reach-v3", "push-v3-n2-s0-from-reach-v3", "local/push-v3", 0, "push-v3"),
                        ("reach-v3", "push-v3-n2-s100-from-reach-v3", "local/push-v3", 100, "push-v3")]
    assert runs[0] == tmp_path / "runs" / "instant_policy-swap" / "reach-v3" / "set-0"
    assert "--env.task=reach-v3" in commands[0] and "--policy.demo_repo_id=local/reach-v3" in commands[0]
    assert f"--policy.demo_root={tmp_path / 'demos' / 'reach-v3-n2-s0-from-push-v3'}" in commands[0]
    assert "--env.type=metaworld_pointcloud" in commands[0] and "--env.pointcloud_every=8" in commands[0]
    assert "--env.render_size=64" in commands[0]
    assert json.loads((runs[0] / suite.CELL_FILE).read_text())["env_args"] == []  # the videos' size decides nothing
    mt10 = swap_sources(list(MT10_TASKS), metaworld_suite.swap_group)
    assert all(metaworld_suite.swap_group(task) != metaworld_suite.swap_group(source) for task, source in mt10.items())


def test_resume_keeps_the_finished_cells_of_the_named_run_and_refuses_other_settings(monkeypatch, tmp_path, capsys):
    """``lerobot-ip-eval-metaworld --resume`` after an interrupted run: the cells that finished under the same
    settings are kept and only the missing one is evaluated, under ``--run-name``; a cell evaluated with another
    episode length is refused before anything runs. ``lerobot-eval`` is replaced by a stand-in writing its
    ``eval_info.json`` (the real call runs in the end-to-end test above)."""
    from lerobot_instant_policy.cli.eval_metaworld import main as eval_metaworld_main
    from lerobot_instant_policy.evaluation import suite

    evaluated = []

    def fake_lerobot_eval(command, runs_dir, task, demo_set):
        output_dir = runs_dir / task / f"set-{demo_set}"
        output_dir.mkdir(parents=True, exist_ok=True)
        info = {"per_task": [{"task_group": task, "task_id": 0, "metrics": {"successes": [True, False]}}],
                "overall": {"pc_success": 50.0, "n_episodes": 2}}
        (output_dir / "eval_info.json").write_text(json.dumps(info))
        evaluated.append((task, demo_set))
        return output_dir

    monkeypatch.setattr(suite, "run_lerobot_eval", fake_lerobot_eval)
    common = ["--policy", "do_nothing", "--tasks", "reach-v3,push-v3", "--episodes", "2", "--demo-sets", "2",
              "--out", str(tmp_path), "--run-name", "still"]
    assert eval_metaworld_main(common) == 0
    assert evaluated == [("reach-v3", 0), ("reach-v3", 1), ("push-v3", 0), ("push-v3", 1)]
    runs = tmp_path / "runs" / "still"
    assert json.loads((runs / "push-v3" / "set-1" / "suite_cell.json").read_text())["episode_length"] == 200
    (runs / "push-v3" / "set-1" / "eval_info.json").unlink()  # interrupted in the last cell

    evaluated.clear()
    capsys.readouterr()
    assert eval_metaworld_main([*common, "--resume"]) == 0
    assert evaluated == [("push-v3", 1)]
    assert capsys.readouterr().out.count("kept from the earlier run") == 3
    assert eval_metaworld_main([*common, "--resume", "--episode-length", "100"]) == 2
    assert "episode_length" in capsys.readouterr().err and evaluated == [("push-v3", 1)]
    results = json.loads((tmp_path / "success_table_still.json").read_text())["rows"]
    assert {(row["task"], row["episodes"], row["successes"]) for row in results} == {("reach-v3", 4, 2),
                                                                                     ("push-v3", 4, 2)}
    with pytest.raises(SystemExit):
        eval_metaworld_main([*common, "--run-name", "../elsewhere"])


@pytest.mark.parametrize("overrides, tasks, message", [
    ({"policy": "do_nothing", "swap": True}, ["reach-v3", "push-v3"], "needs a policy that reads demonstrations"),
    ({"swap": True}, ["reach-v3"], "at least two tasks"),
    ({"episode_length": 600}, ["reach-v3"], "MetaWorld's limit"),
    ({"success": "instant"}, ["reach-v3"], "success applies to bullet_tabletop only"),
    ({"policy": "metaworld_expert", "env_type": "bullet_tabletop"}, ["push_button"], "policy must be one of"),
])
def test_bad_metaworld_suite_settings_are_refused_before_anything_runs(tmp_path, overrides, tasks, message):
    from lerobot_instant_policy.evaluation.suite import SuiteError, SuiteSettings, run_suite

    settings = SuiteSettings(**{"env_type": "metaworld_pointcloud", "out": tmp_path, **overrides})
    with pytest.raises(SuiteError, match=message):
        run_suite(settings, tasks, report=lambda line: None)
    assert not (tmp_path / "runs").exists()
