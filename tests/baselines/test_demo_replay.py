"""The ``demo_replay`` baseline through LeRobot's own factory: it replays a demonstration moved to where the object
is now, each env of a batch with its own plan, and it saves and loads like any LeRobot policy."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from synthetic_demos import (
    NUM_FRAMES,
    expected_actions,
    make_demonstration,
    object_cloud,
    object_pose,
    write_demo_dataset,
)

from lerobot_instant_policy.contract import POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.data.demonstrations import DemonstrationError
from lerobot_instant_policy.geometry.se3 import make_pose, pose_distance, pose_from_pos_quat
from lerobot_instant_policy.replay.plan import transform_pose_actions

REPO_ID = "local/lift_demos"
TASK = "lift"


@pytest.fixture(scope="module")
def demo_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("replay") / "demos"
    write_demo_dataset(root, REPO_ID, [(TASK, object_pose(0.5, 0.0, 0.0)), ("push", object_pose(0.5, 0.1, 10.0)),
                                       (TASK, object_pose(0.45, -0.1, 35.0))])
    return root


def make_demo_replay(**overrides):
    """``demo_replay`` built the way ``lerobot-eval --policy.type=demo_replay`` builds it (no pretrained path)."""
    from lerobot.policies.factory import get_policy_class, make_policy_config, make_pre_post_processors

    config = make_policy_config("demo_replay", device="cpu", **overrides)
    policy = get_policy_class("demo_replay")(config)
    preprocessor, postprocessor = make_pre_post_processors(config)
    return policy, preprocessor, postprocessor


def run_episode(policy, preprocessor, postprocessor, clouds: np.ndarray, tasks: list[str] | None, steps: int) -> np.ndarray:
    """Actions ``(B, steps, 8)`` for a batch whose object clouds stay ``clouds (B, P, 3)``."""
    policy.reset()
    actions = []
    for _ in range(steps):
        batch = {POINTCLOUD_KEY: torch.from_numpy(clouds), STATE_KEY: torch.zeros(len(clouds), 8)}
        if tasks is not None:
            batch["task"] = tasks
        with torch.inference_mode():
            actions.append(postprocessor(policy.select_action(preprocessor(batch))).numpy())
    return np.stack(actions, axis=1)


def assert_actions_close(actual: np.ndarray, expected: np.ndarray, position_m: float = 0.006, angle_deg: float = 3.0):
    for got, want in zip(actual, expected):
        translation, angle = pose_distance(pose_from_pos_quat(got[:3], got[3:7]), pose_from_pos_quat(want[:3], want[3:7]))
        assert translation < position_m and np.degrees(angle) < angle_deg, (got, want)
    np.testing.assert_array_equal(actual[:, 7], expected[:, 7])


def test_factory_resolves_the_registered_policy():
    from lerobot.policies.factory import get_policy_class, make_policy_config

    from lerobot_instant_policy.baselines.modeling_demo_replay import DemoReplayPolicy

    assert get_policy_class("demo_replay") is DemoReplayPolicy
    config = make_policy_config("demo_replay")
    assert config.push_to_hub is False and config.num_demos == 2
    with pytest.raises(ValueError, match="num_demos must be at least 1"):
        make_policy_config("demo_replay", num_demos=0)


def test_the_plan_options_are_named_as_instant_policys():
    """``replay_per_object`` / ``replay_anchored`` / ``replay_consensus`` choose the plan as ``InstantPolicyConfig``'s
    fields of those names do; they exclude each other."""
    from lerobot.policies.factory import make_policy_config

    from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig

    for per_object, anchored, consensus in ((False, False, False), (True, False, False), (False, True, False),
                                            (False, False, True)):
        options = {"replay_per_object": per_object, "replay_anchored": anchored, "replay_consensus": consensus}
        assert (make_policy_config("demo_replay", **options).replay_plan()
                == InstantPolicyConfig(device="cpu", **options).replay_plan())
    with pytest.raises(ValueError, match="not two"):
        make_policy_config("demo_replay", replay_per_object=True, replay_anchored=True)
    with pytest.raises(ValueError, match="not two"):
        InstantPolicyConfig(device="cpu", replay_anchored=True, replay_consensus=True)


def test_make_policy_with_dataset_metadata(demo_root):
    """``make_policy`` (LeRobot's factory) builds it from a dataset's features, as ``lerobot-train`` would."""
    from lerobot.datasets import LeRobotDatasetMetadata
    from lerobot.policies.factory import make_policy, make_policy_config

    config = make_policy_config("demo_replay", device="cpu", demo_repo_id=REPO_ID, demo_root=str(demo_root))
    policy = make_policy(config, ds_meta=LeRobotDatasetMetadata(REPO_ID, root=demo_root))
    assert policy.config.output_features["action"].shape == (8,)
    assert policy.get_optim_params() == []
    with pytest.raises(RuntimeError, match="no trainable parameters"):
        policy.forward({})


def test_replays_the_demonstration_where_the_object_moved(demo_root):
    policy, preprocessor, postprocessor = make_demo_replay(demo_repo_id=REPO_ID, demo_root=str(demo_root))
    T_world_object_now = object_pose(0.58, 0.12, -50.0)
    cloud_now = object_cloud(T_world_object_now, seed=99)[None]
    actions = run_episode(policy, preprocessor, postprocessor, cloud_now, [TASK], NUM_FRAMES + 3)[0]
    expected = expected_actions(T_world_object_now)
    assert_actions_close(actions[:NUM_FRAMES], expected)
    assert_actions_close(actions[NUM_FRAMES:], np.repeat(expected[-1:], 3, axis=0))
    assert policy.plans[0].task == TASK


def test_batch_of_two_gets_two_plans(demo_root):
    policy, preprocessor, postprocessor = make_demo_replay(demo_repo_id=REPO_ID, demo_root=str(demo_root))
    poses = [object_pose(0.42, -0.15, 50.0), object_pose(0.6, 0.1, -30.0)]
    clouds = np.stack([object_cloud(pose, seed=200 + index) for index, pose in enumerate(poses)])
    actions = run_episode(policy, preprocessor, postprocessor, clouds, [TASK, TASK], NUM_FRAMES)
    for index, pose in enumerate(poses):
        assert_actions_close(actions[index], expected_actions(pose))
    assert np.linalg.norm(actions[0, 0, :3] - actions[1, 0, :3]) > 0.1

    # a new episode (reset) plans again for the new scene
    moved = object_cloud(object_pose(0.5, 0.0, 10.0), seed=300)[None].repeat(2, axis=0)
    again = run_episode(policy, preprocessor, postprocessor, moved, [TASK, TASK], 2)
    assert_actions_close(again[0], expected_actions(object_pose(0.5, 0.0, 10.0))[:2])
    chunk = policy.predict_action_chunk({POINTCLOUD_KEY: torch.from_numpy(moved), STATE_KEY: torch.zeros(2, 8)})
    assert chunk.shape == (2, NUM_FRAMES - 2, 8)
    np.testing.assert_allclose(chunk[0].numpy(), policy.plans[0].actions[2:], atol=1e-6)


def test_picks_the_demonstration_that_fits(tmp_path):
    """Two demonstrations of one task on different objects: the one whose object is in the scene is replayed."""
    duck_demo = make_demonstration(object_pose(0.5, 0.0, 0.0), TASK, seed=1, object_id="pb/duck")
    mug_demo = make_demonstration(object_pose(0.5, 0.0, 0.0), TASK, seed=2)
    policy, preprocessor, postprocessor = make_demo_replay()
    policy.set_demonstrations([mug_demo, duck_demo])
    T_world_duck_now = object_pose(0.45, 0.1, 30.0)
    cloud_now = object_cloud(T_world_duck_now, seed=3, object_id="pb/duck")[None]
    actions = run_episode(policy, preprocessor, postprocessor, cloud_now, None, NUM_FRAMES)[0]
    assert policy.plans[0].demo_index == 1
    assert_actions_close(actions, expected_actions(T_world_duck_now))


def test_save_and_load_round_trip(tmp_path, demo_root):
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    policy, preprocessor, postprocessor = make_demo_replay(
        demo_repo_id=REPO_ID, demo_root=str(demo_root), num_demos=1, registration_yaw_only=False, registration_overlap=0.9
    )
    policy.save_pretrained(tmp_path / "ckpt")
    preprocessor.save_pretrained(tmp_path / "ckpt")
    postprocessor.save_pretrained(tmp_path / "ckpt")
    loaded = get_policy_class("demo_replay").from_pretrained(tmp_path / "ckpt")
    assert (loaded.config.demo_repo_id, loaded.config.demo_root, loaded.config.num_demos) == (REPO_ID, str(demo_root), 1)
    assert loaded.config.registration_yaw_only is False and loaded.config.registration_overlap == 0.9
    loaded_pre, loaded_post = make_pre_post_processors(loaded.config, pretrained_path=str(tmp_path / "ckpt"))
    cloud = object_cloud(object_pose(0.55, 0.05, 25.0), seed=5)[None]
    np.testing.assert_allclose(
        run_episode(loaded, loaded_pre, loaded_post, cloud, [TASK], 4),
        run_episode(policy, preprocessor, postprocessor, cloud, [TASK], 4),
        atol=1e-6,
    )


def test_clear_errors_for_missing_demonstrations(tmp_path, demo_root):
    cloud = object_cloud(object_pose(0.5, 0.0, 0.0), seed=0)[None]
    policy, preprocessor, postprocessor = make_demo_replay()
    with pytest.raises(DemonstrationError, match="set --policy.demo_repo_id"):
        run_episode(policy, preprocessor, postprocessor, cloud, [TASK], 1)
    policy, preprocessor, postprocessor = make_demo_replay(demo_repo_id=REPO_ID, demo_root=str(demo_root))
    with pytest.raises(DemonstrationError, match=r"no episode of task 'open_box'.*\['lift', 'push'\]"):
        run_episode(policy, preprocessor, postprocessor, cloud, ["open_box"], 1)
    with pytest.raises(DemonstrationError, match="does not exist"):
        run_episode(*make_demo_replay(demo_repo_id=REPO_ID, demo_root=str(tmp_path / "missing")), cloud, [TASK], 1)


def test_transform_pose_actions_composes_poses():
    rng = np.random.default_rng(0)
    from scipy.spatial.transform import Rotation

    actions = np.concatenate(
        [rng.uniform(-0.5, 0.5, (5, 3)), Rotation.random(5, random_state=1).as_quat(), rng.integers(0, 2, (5, 1))], axis=1
    ).astype(np.float32)
    T_now_demo = make_pose(np.array([0.1, -0.2, 0.05]), Rotation.from_euler("xyz", [10, -20, 70], degrees=True))
    moved = transform_pose_actions(T_now_demo, actions)
    for before, after in zip(actions, moved):
        expected = T_now_demo @ pose_from_pos_quat(before[:3], before[3:7])
        translation, angle = pose_distance(pose_from_pos_quat(after[:3], after[3:7]), expected)
        assert translation < 1e-6 and angle < 1e-5
        assert after[6] >= 0 and after[7] == before[7]
