"""Targets from a demonstration dataset with the shipped checkpoint, their cache, and ``lerobot-ip-train-language``
end to end: targets, training, a saved head that then drives ψ from a sentence."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lerobot_instant_policy.cli.train_language import main
from lerobot_instant_policy.contract import poses_from_vectors_torch
from lerobot_instant_policy.data.demonstrations import open_demo_dataset, read_demonstration
from lerobot_instant_policy.language.context import language_context
from lerobot_instant_policy.language.language_head import LanguageHead
from lerobot_instant_policy.language.paraphrases import ParaphraseError, Paraphrases
from lerobot_instant_policy.training import language_targets as targets_module
from lerobot_instant_policy.training.language_targets import (
    LanguageTargets,
    TargetsError,
    build_targets,
    cached_targets,
)

pytestmark = pytest.mark.usefixtures("single_torch_thread")
FRAMES = 4  # of each 12-frame live episode: 0, 4, 7, 11


@pytest.fixture(scope="module")
def dataset_targets(shipped_policy, demo_dataset, paraphrases) -> LanguageTargets:
    return build_targets(shipped_policy, demo_dataset.root, num_demos=2, frames_per_episode=FRAMES,
                         paraphrases=paraphrases)


def test_targets_hold_every_live_frame_with_its_bottleneck(shipped_policy, demo_dataset, dataset_targets):
    targets = dataset_targets
    tasks, episodes = len(demo_dataset.tasks), demo_dataset.episodes_per_task
    assert targets.tasks == list(demo_dataset.tasks) and targets.num_frames == tasks * episodes * FRAMES
    assert targets.bottleneck.shape == (targets.num_frames, 6, 128) and np.isfinite(targets.bottleneck).all()
    assert targets.scene_positions.shape == (targets.num_frames, 16, 3)
    assert targets.scene_features.shape == (targets.num_frames, 16, 256)
    np.testing.assert_array_equal(targets.frame_index[:FRAMES], [0, 4, 7, 11])
    np.testing.assert_array_equal(np.unique(targets.episode_index), np.arange(tasks * episodes))
    assert targets.build["num_demos"] == 2 and targets.build["frames_per_episode"] == FRAMES
    # each row is the frame it names: its scene nodes are the encoder's on that frame's cloud in its EE frame
    row = 5
    dataset = open_demo_dataset("local/demos", demo_dataset.root)
    demo = read_demonstration(dataset, int(targets.episode_index[row]), targets.tasks[targets.task_index[row]])
    frame = int(targets.frame_index[row])
    T_world_ee, gripper_open = poses_from_vectors_torch(torch.from_numpy(demo.state[frame:frame + 1]))
    positions, _ = shipped_policy.network.encode_observation(torch.from_numpy(demo.points_world[frame:frame + 1]),
                                                             T_world_ee)
    np.testing.assert_allclose(targets.scene_positions[row], positions[0].numpy(), atol=1e-5)
    assert targets.gripper_open[row] == float(gripper_open[0] > 0.5)


def test_targets_refuse_what_they_cannot_use(shipped_policy, demo_dataset, tmp_path):
    no_knock_over = Paraphrases({"suite": {"pick_and_lift": {"seen": ["lift it"], "held_out": ["raise it"]}}})
    with pytest.raises(ParaphraseError, match=r"no sentences for the tasks \['knock_over'\]"):
        build_targets(shipped_policy, demo_dataset.root, paraphrases=no_knock_over)
    with pytest.raises(TargetsError, match="has fewer for {'pick_and_lift': 3, 'knock_over': 3}"):
        build_targets(shipped_policy, demo_dataset.root, num_demos=3)
    with pytest.raises(TargetsError, match=r"no episodes of \['open_drawer'\]"):
        build_targets(shipped_policy, demo_dataset.root, tasks=["open_drawer"])


def test_stored_targets_are_reused_only_when_built_the_same_way(shipped_policy, demo_dataset, dataset_targets,
                                                                tmp_path, monkeypatch):
    dataset_targets.save(tmp_path / "targets")
    loaded = LanguageTargets.load(tmp_path / "targets")
    assert loaded.tasks == dataset_targets.tasks and np.array_equal(loaded.bottleneck, dataset_targets.bottleneck)

    def refuse(*args, **kwargs):
        raise AssertionError("built again")

    monkeypatch.setattr(targets_module, "build_targets", refuse)
    reused = cached_targets(tmp_path / "targets", shipped_policy, demo_dataset.root, num_demos=2,
                            frames_per_episode=FRAMES)
    assert np.array_equal(reused.scene_features, dataset_targets.scene_features)
    with pytest.raises(AssertionError, match="built again"):  # another frame count: not the stored targets
        cached_targets(tmp_path / "targets", shipped_policy, demo_dataset.root, num_demos=2, frames_per_episode=3)
    train, held = loaded.split_episodes(0.34)  # one of each task's three episodes held out, the last
    episodes = demo_dataset.episodes_per_task
    assert held.num_frames == len(demo_dataset.tasks) * FRAMES and train.num_frames == 2 * held.num_frames
    assert set(held.episode_index) == {episodes - 1, 2 * episodes - 1}


def test_the_command_trains_a_head_that_drives_the_policy_from_words(shipped_policy, wordllama, demo_dataset, tmp_path,
                                                                    capsys):
    out = tmp_path / "run"
    assert main(["--dataset", str(demo_dataset.root), "--out", str(out), "--frames-per-episode", str(FRAMES),
                 "--steps", "30", "--batch-size", "8", "--val-fraction", "0.34"]) == 0
    captured = capsys.readouterr()
    evaluation = json.loads(captured.out)
    assert set(evaluation) == {"train_seen_sentences", "train_held_out_sentences", "held_out_episodes",
                               "held_out_episodes_untrained_head"}
    tasks = len(demo_dataset.tasks)
    assert evaluation["held_out_episodes"]["frames"] == tasks * FRAMES
    assert "ranking" in captured.err and f"head in {out / 'head'}" in captured.err
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tasks"] == list(demo_dataset.tasks) and len(metrics["history"]) == 1
    assert metrics["frames"] == {"train": 2 * tasks * FRAMES, "held_out_episodes": tasks * FRAMES}
    assert (out / "targets" / "0-demos" / "targets.safetensors").is_file()
    # the saved head, loaded for the checkpoint and encoder it was made for, gives ψ a context from a sentence
    head = LanguageHead.load(out / "head")
    head.check_binding(shipped_policy.network, wordllama)
    demo = read_demonstration(open_demo_dataset("local/demos", demo_dataset.root), 0, "pick_and_lift")
    T_world_ee, gripper = poses_from_vectors_torch(torch.from_numpy(demo.state[:1]))
    context = language_context(shipped_policy.network, head, torch.from_numpy(wordllama.encode(["pick up the block"])),
                               torch.from_numpy(demo.points_world[:1]), T_world_ee, gripper)
    T_ee_actions, action_gripper = shipped_policy.network.sample_actions(context, torch.Generator().manual_seed(0))
    assert T_ee_actions.shape == (1, 8, 4, 4) and torch.isfinite(T_ee_actions).all() and action_gripper.shape == (1, 8)


def test_the_command_refuses_bad_inputs_with_exit_status_2(demo_dataset, tmp_path, capsys):
    assert main(["--dataset", str(demo_dataset.root), "--out", str(tmp_path), "--text-encoder", "bert"]) == 2
    assert "unknown text encoder 'bert'" in capsys.readouterr().err
    assert main(["--dataset", str(tmp_path / "nothing"), "--out", str(tmp_path)]) == 2
    assert "demonstration dataset root" in capsys.readouterr().err
