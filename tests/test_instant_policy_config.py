"""``InstantPolicyConfig`` (``--policy.type=instant_policy``): registration, presets, validation, CLI parsing, JSON
round trip; and ``make_instant_policy_pre_post_processors`` (LeRobot's default steps, IDENTITY normalisation, the
point-cloud batch step)."""

from __future__ import annotations

import json

import draccus
import pytest
import torch
from lerobot.configs import FeatureType, NormalizationMode, PolicyFeature, PreTrainedConfig

import lerobot_instant_policy  # noqa: F401  (registers the config)
from lerobot_instant_policy.configuration_instant_policy import (
    DEFAULT_GRIPPER_KEYPOINTS,
    PRESETS,
    SHIPPED_ENCODER_DIR,
    InstantPolicyConfig,
)
from lerobot_instant_policy.contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.model.occupancy import OccupancyNetwork, save_occupancy_network
from lerobot_instant_policy.processor_instant_policy import make_instant_policy_pre_post_processors


def config(**overrides) -> InstantPolicyConfig:
    return InstantPolicyConfig(device="cpu", **overrides)


def test_registered_as_instant_policy_on_package_import():
    assert PreTrainedConfig.get_choice_class("instant_policy") is InstantPolicyConfig
    assert config().type == "instant_policy"


def test_defaults_follow_the_paper_and_lerobot_facts():
    cfg = config()
    assert (cfg.num_demos, cfg.num_waypoints, cfg.horizon, cfg.inference_steps) == (2, 10, 8, 4)
    assert (cfg.min_demos, cfg.diffusion_train_steps, cfg.num_scene_nodes) == (1, 100, 16)
    assert cfg.gripper_keypoints == [list(point) for point in DEFAULT_GRIPPER_KEYPOINTS]
    assert cfg.gripper_flip_probability == 0.1
    assert cfg.push_to_hub is False
    assert set(cfg.normalization_mapping.values()) == {NormalizationMode.IDENTITY}
    assert cfg.observation_delta_indices is None and cfg.reward_delta_indices is None
    # LeRobot delivers each row's own action; the policy reads the chunk itself (tests/data/test_action_chunks.py).
    assert cfg.action_delta_indices is None
    assert cfg.encoder_weights_path() == SHIPPED_ENCODER_DIR / "small.safetensors"


def test_defaults_are_the_shipped_model_so_no_flag_trains_it():
    """``lerobot-train --policy.type=instant_policy`` with no policy flag trains the shipped checkpoint's model and
    recipe: its config.json holds every field of the config and nothing else, each with the default's value, but
    ``type`` (which LeRobot writes beside the fields) and ``pretrained_path`` (which LeRobot sets when it loads
    one)."""
    from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT

    shipped = json.loads((SHIPPED_CHECKPOINT / "config.json").read_text())
    defaults = json.loads(json.dumps(draccus.encode(config())))
    assert set(shipped) - {"type"} == set(defaults)
    assert shipped["type"] == "instant_policy"
    differing = {key: (shipped[key], value) for key, value in defaults.items()
                 if key != "pretrained_path" and shipped[key] != value}
    assert differing == {}
    assert defaults["use_amp"] is False  # not the checkpoint's: bfloat16 autocast is the machine's choice


def test_the_paper_preset_is_the_papers_graph_and_context():
    paper = config(preset="paper", pretrained_encoder=False)
    assert (paper.action_scene_graph, paper.reencode_action_clouds, paper.num_frequencies, paper.max_demos) == (
        True, True, 10, 5)
    small = config()
    assert (small.action_scene_graph, small.reencode_action_clouds, small.num_frequencies, small.max_demos) == (
        False, False, 4, 2)
    # one option of the paper's graph on the small model: explicit values win over the preset
    assert config(action_scene_graph=True).action_scene_graph and not config(action_scene_graph=True).reencode_action_clouds


def test_the_refined_preset_is_the_small_model_trained_and_run_from_the_replay():
    refined, small = config(preset="refined"), config()
    assert (refined.refine_fraction, refined.replay_init_strength, refined.replay_per_object) == (0.5, 0.25, True)
    assert (small.refine_fraction, small.replay_init_strength, small.replay_per_object) == (0.0, None, False)
    sizes = ("hidden_dim", "num_heads", "local_layers", "context_layers", "action_layers", "encoder_preset",
             "max_demos")
    assert [getattr(refined, name) for name in sizes] == [getattr(small, name) for name in sizes]
    assert config(preset="refined", refine_fraction=0.2, replay_init_strength=0.5).refine_fraction == 0.2


@pytest.mark.parametrize("fast_bfloat16", [True, False])
def test_use_amp_is_deactivated_on_a_cpu_without_fast_bfloat16(monkeypatch, caplog, fast_bfloat16):
    from lerobot_instant_policy import configuration_instant_policy

    monkeypatch.setattr(configuration_instant_policy, "cpu_has_fast_bfloat16", lambda: fast_bfloat16)
    assert config(use_amp=True).use_amp is fast_bfloat16
    assert ("use_amp deactivated" in caplog.text) is not fast_bfloat16
    assert config(use_amp=False).use_amp is False


@pytest.mark.parametrize("preset", ["small", "paper"])
def test_preset_fills_every_size_left_unset(preset):
    cfg = config(preset=preset)
    values = PRESETS[preset]
    assert cfg.hidden_dim == values.hidden_dim and cfg.num_heads == values.num_heads
    assert (cfg.local_layers, cfg.context_layers, cfg.action_layers) == (
        values.local_layers,
        values.context_layers,
        values.action_layers,
    )
    assert cfg.encoder_preset == values.encoder_preset and cfg.optimizer_lr == values.optimizer_lr
    assert (cfg.num_frequencies, cfg.action_scene_graph, cfg.reencode_action_clouds, cfg.max_demos) == (
        values.num_frequencies, values.action_scene_graph, values.reencode_action_clouds, values.max_demos)


def test_paper_preset_is_the_papers_model_and_small_is_smaller():
    paper, small = config(preset="paper"), config(preset="small")
    assert (paper.hidden_dim, paper.num_heads, paper.optimizer_lr) == (1024, 16, 1e-5)
    assert small.hidden_dim < paper.hidden_dim and small.optimizer_lr > paper.optimizer_lr


def test_explicit_sizes_win_over_the_preset():
    cfg = config(preset="paper", hidden_dim=256, num_heads=8, optimizer_lr=3e-4, encoder_preset="small")
    assert (cfg.hidden_dim, cfg.num_heads, cfg.optimizer_lr, cfg.encoder_preset) == (256, 8, 3e-4, "small")
    assert cfg.context_layers == PRESETS["paper"].context_layers


def test_optimizer_and_scheduler_presets():
    cfg = config(preset="small", optimizer_grad_clip_norm=0.5, scheduler_warmup_steps=10)
    optimizer_config = cfg.get_optimizer_preset()
    assert optimizer_config.type == "instant_policy_adamw"
    assert (optimizer_config.lr, optimizer_config.grad_clip_norm) == (2e-4, 0.5)
    parameter = torch.nn.Parameter(torch.zeros(3))
    optimizer = optimizer_config.build([parameter])
    assert isinstance(optimizer, torch.optim.AdamW) and optimizer.defaults["fused"]  # fused on the CPU
    scheduler = cfg.get_scheduler_preset().build(optimizer, num_training_steps=100)
    rates = []
    for _ in range(100):
        rates.append(optimizer.param_groups[0]["lr"])
        optimizer.step()
        scheduler.step()
    assert rates[0] == 0.0 and rates[10] == pytest.approx(2e-4)  # linear warmup to the peak
    assert rates[55] == pytest.approx(1e-4, rel=1e-3) and rates[-1] < 2e-6  # then cosine decay to zero


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"preset": "huge"}, r"unknown preset 'huge'; known presets: \['paper', 'refined', 'small'\]"),
        ({"num_demos": 0}, r"num_demos \(N\) must be an integer in the supported range 1…8, got 0"),
        ({"num_demos": 9}, r"num_demos \(N\) must be an integer in the supported range"),
        ({"max_demos": 9}, "max_demos must be an integer in the supported range"),
        ({"min_demos": 4, "max_demos": 3}, r"min_demos \(4\) must not exceed max_demos \(3\)"),
        ({"num_waypoints": 1}, r"num_waypoints \(L\) must be an integer in the supported range 2…32, got 1"),
        ({"num_waypoints": 33}, r"num_waypoints \(L\) must be an integer in the supported range"),
        ({"horizon": 0}, r"horizon \(T\) must be an integer in the supported range"),
        ({"inference_steps": 0}, r"inference_steps \(K\) must be an integer in the supported range 1…8, got 0"),
        ({"inference_steps": 9}, r"inference_steps \(K\) must be an integer in the supported range 1…8, got 9"),
        ({"diffusion_train_steps": 3}, r"diffusion_train_steps \(3\) must be at least inference_steps \(4\)"),
        ({"n_action_steps": 9}, r"n_action_steps must lie in 1…horizon \(8\), got 9"),
        ({"horizon": 4, "n_action_steps": 5}, r"n_action_steps must lie in 1…horizon \(4\), got 5"),
        ({"n_action_steps": 0}, "n_action_steps must lie in"),
        ({"n_obs_steps": 2}, "n_obs_steps must be 1"),
        ({"hidden_dim": 100, "num_heads": 16}, r"hidden_dim \(100\) must be divisible by num_heads \(16\)"),
        ({"local_layers": 0}, "local_layers must be at least 1"),
        ({"num_scene_nodes": 32}, r"num_scene_nodes \(M=32\) must equal the 'small' geometry encoder's 16"),
        ({"encoder_preset": "tiny"}, r"unknown encoder preset 'tiny'"),
        ({"gripper_keypoints": [[0.0, 0.0]]}, r"gripper_keypoints must be a list of finite \(x, y, z\) points"),
        ({"gripper_keypoints": [[0.0, 0.0, float("nan")]] * 3}, "gripper_keypoints must be a list of finite"),
        ({"gripper_keypoints": [[0.0, 0.0, z] for z in (0.0, 0.1, 0.2)]}, "at least 3 points not on one line"),
        ({"gripper_keypoints": [[0.0, 0.0, 0.0]] * 3}, "at least 3 points not on one line"),
        ({"gripper_flip_probability": 1.5}, r"gripper_flip_probability must lie in \[0, 1\]"),
        ({"refine_fraction": 1.5}, r"refine_fraction must lie in \[0, 1\], got 1.5"),
        ({"refine_fraction": -0.1}, r"refine_fraction must lie in \[0, 1\]"),
        ({"refine_max_strength": 0.0}, r"refine_max_strength must lie in \(0, 1\], got 0.0"),
        ({"optimizer_lr": 0.0}, "optimizer_lr and optimizer_grad_clip_norm must be positive"),
        ({"encoder_weights": "weights.pt"}, "encoder_weights must name a .safetensors file"),
        ({"mlp_ratio": 0}, "mlp_ratio must be at least 1"),
        ({"compile_mode": "fast"}, r"compile_mode must be one of \['default', 'reduce-overhead'"),
        ({"max_translation": 0.0}, "max_translation and max_rotation_deg must be positive"),
        ({"replay_init_strength": 0.0}, r"replay_init_strength must lie in \(0, 1\] or be None, got 0.0"),
        ({"replay_init_strength": 1.5}, r"replay_init_strength must lie in \(0, 1\]"),
        ({"samples_per_prediction": 0}, r"samples_per_prediction \(S\) must be an integer in the supported range 1…64, "
                                        r"got 0"),
        ({"samples_per_prediction": 65}, r"samples_per_prediction \(S\) must be an integer in the supported range"),
    ],
)
def test_invalid_values_are_refused_with_a_clear_message(overrides, message):
    with pytest.raises(ValueError, match=message):
        config(**overrides)


def test_encoder_weights_must_match_the_encoder_preset(tmp_path):
    """The config reads no file; the policy loads the weights in an explicit step and refuses another architecture."""
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    path = tmp_path / "encoder.safetensors"
    save_occupancy_network(OccupancyNetwork.from_preset("small"), path)
    assert config(encoder_weights=str(path)).encoder_weights_path() == path
    paper = config(encoder_preset="paper", encoder_weights=str(path))  # building the config reads nothing
    with pytest.raises(ValueError, match=r"encoder weights .*encoder\.safetensors were trained for config .*"
                       r"which does not match the requested"):
        InstantPolicyPolicy(paper)
    InstantPolicyPolicy(config(encoder_weights=str(path)))  # the matching architecture loads
    InstantPolicyPolicy(config(preset="paper", encoder_preset="small", hidden_dim=64, num_heads=4,
                               encoder_weights=str(tmp_path / "absent.safetensors"), pretrained_encoder=False))


def test_missing_encoder_weights_say_how_to_get_them(tmp_path):
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    cfg = config(encoder_weights=str(tmp_path / "missing.safetensors"))  # a checkpoint carries its encoder
    with pytest.raises(FileNotFoundError, match=r"no geometry encoder weights at .*missing\.safetensors: train them "
                       r"with `lerobot-ip-pretrain-encoder --preset small"):
        InstantPolicyPolicy(cfg)


def test_validate_features_names_what_is_missing_or_wrong():
    config().validate_features()
    cfg = config(
        input_features={STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(7,))},
        output_features={ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(8,))},
    )
    with pytest.raises(ValueError, match=r"input 'observation.pointcloud' of shape \(P, 3\), got nothing; "
                       r"input 'observation.state' of shape \(8,\), got \(7,\)"):
        cfg.validate_features()
    cloud = config(input_features={
        POINTCLOUD_KEY: PolicyFeature(type=FeatureType.STATE, shape=(1024, 3)),
        STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(8,)),
    })
    cloud.validate_features()
    assert cloud.num_points == 1024
    few = config(input_features={
        POINTCLOUD_KEY: PolicyFeature(type=FeatureType.STATE, shape=(100, 3)),
        STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(8,)),
    })
    with pytest.raises(ValueError, match="clouds of 100 points are fewer than the 'small' geometry encoder's 256"):
        few.validate_features()


def test_cli_flags_select_the_preset_and_override_fields():
    from lerobot.configs.train import TrainPipelineConfig

    args = ["--policy.type=instant_policy", "--policy.preset=paper", "--policy.num_demos=3",
            "--policy.device=cpu", "--dataset.repo_id=local/x"]
    parsed = draccus.parse(TrainPipelineConfig, args=args)
    assert isinstance(parsed.policy, InstantPolicyConfig)
    assert (parsed.policy.preset, parsed.policy.hidden_dim, parsed.policy.num_demos) == ("paper", 1024, 3)
    assert parsed.policy.push_to_hub is False
    small = draccus.parse(TrainPipelineConfig, args=["--policy.type=instant_policy", "--policy.preset=small",
                                                     "--policy.hidden_dim=64", "--dataset.repo_id=local/x"])
    assert (small.policy.hidden_dim, small.policy.num_heads) == (64, PRESETS["small"].num_heads)


def test_json_round_trip_without_pickle(tmp_path):
    cfg = config(preset="paper", num_demos=3, horizon=6, n_action_steps=4, encoder_preset="small",
                 reencode_action_clouds=False, demo_repo_id="local/demos", demo_root="/data/demos")
    cfg.save_pretrained(tmp_path)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["config.json"]
    saved = json.loads((tmp_path / "config.json").read_text())
    assert saved["type"] == "instant_policy" and saved["hidden_dim"] == 1024
    loaded = PreTrainedConfig.from_pretrained(tmp_path)
    assert isinstance(loaded, InstantPolicyConfig)
    assert loaded == cfg
    assert b"pickle" not in (tmp_path / "config.json").read_bytes()


def test_processors_are_lerobots_default_steps_and_leave_values_unchanged(tmp_path):
    cfg = config()
    preprocessor, postprocessor = make_instant_policy_pre_post_processors(cfg)
    names = [type(step).__name__ for step in preprocessor.steps]
    assert names == ["RenameObservationsProcessorStep", "AddBatchDimensionProcessorStep",
                     "AddPointCloudBatchDimensionStep", "DeviceProcessorStep", "NormalizerProcessorStep"]
    assert [type(step).__name__ for step in postprocessor.steps] == ["UnnormalizerProcessorStep", "DeviceProcessorStep"]
    cloud = torch.randn(2048, 3)
    state = torch.tensor([0.5, 0.1, 0.3, 0.0, 0.0, 0.0, 1.0, 1.0])
    batch = preprocessor({POINTCLOUD_KEY: cloud, STATE_KEY: state, ACTION_KEY: state.clone(), "task": "lift"})
    # LeRobot's batch step gives the 1-D state its batch dimension, ours the (P, 3) cloud
    assert batch[STATE_KEY].shape == (1, 8) and batch[POINTCLOUD_KEY].shape == (1, 2048, 3)
    torch.testing.assert_close(batch[POINTCLOUD_KEY][0], cloud, rtol=0, atol=0)
    torch.testing.assert_close(batch[STATE_KEY][0], state, rtol=0, atol=0)
    action = torch.randn(1, 8)
    torch.testing.assert_close(postprocessor(action), action, rtol=0, atol=0)

    from lerobot.policies.factory import make_pre_post_processors

    preprocessor.save_pretrained(tmp_path)
    postprocessor.save_pretrained(tmp_path)
    loaded, _ = make_pre_post_processors(cfg, pretrained_path=str(tmp_path))
    assert [type(step).__name__ for step in loaded.steps] == names
    again = loaded({POINTCLOUD_KEY: cloud, STATE_KEY: state, ACTION_KEY: state.clone(), "task": "lift"})
    torch.testing.assert_close(again[POINTCLOUD_KEY][0], cloud, rtol=0, atol=0)
