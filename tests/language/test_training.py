"""The loss, the training loop and the evaluation of the language head, on the synthetic targets of conftest (the same
scenes under three tasks with different bottlenecks: only the sentence tells them apart)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from lerobot_instant_policy.language.language_head import HeadBinding, LanguageHead, LanguageHeadConfig
from lerobot_instant_policy.language.paraphrases import ParaphraseError
from lerobot_instant_policy.training.language_head_training import (
    TrainSettings,
    evaluate_language_head,
    language_head_loss,
    train_language_head,
)

pytestmark = pytest.mark.usefixtures("single_torch_thread")

FAST = TrainSettings(steps=60, batch_size=16, lr=3e-3, log_every=20)


def test_the_loss_is_mse_plus_infonce_over_tasks():
    config = LanguageHeadConfig(temperature=0.5, regression_weight=1.0, contrastive_weight=2.0)
    target = torch.tensor([[[1.0, 0.0]], [[0.0, 1.0]]])  # (B=2, G=1, H=2), orthogonal
    exact = language_head_loss(target, target, torch.tensor([0, 1]), config)
    assert float(exact["regression"]) == 0.0
    assert math.isclose(float(exact["contrastive"]), math.log(1 + math.exp(-1 / 0.5)), rel_tol=1e-6)
    assert math.isclose(float(exact["loss"]), 2.0 * float(exact["contrastive"]), rel_tol=1e-6)
    swapped = language_head_loss(target.flip(0), target, torch.tensor([0, 1]), config)
    assert float(swapped["contrastive"]) > float(exact["contrastive"]) + 1.0  # nearer the other task's target: worse
    assert float(language_head_loss(target.flip(0), target, torch.tensor([3, 3]), config)["contrastive"]) == 0.0


def test_training_lowers_the_loss_and_the_words_pick_the_task(shipped_policy, synthetic_targets, paraphrases,
                                                               wordllama):
    network = shipped_policy.network
    trained = train_language_head(network, synthetic_targets, paraphrases, wordllama, settings=FAST)
    first, last = trained.history[0], trained.history[-1]
    assert [entry["step"] for entry in trained.history] == [20, 40, 60]
    assert last["loss"] < 0.5 * first["loss"] and last["regression"] < 0.6 * first["regression"], trained.history
    torch.manual_seed(0)
    untrained = LanguageHead(LanguageHeadConfig(), HeadBinding.of(network, wordllama)).eval()
    before = evaluate_language_head(untrained, network, synthetic_targets, paraphrases, wordllama, "held_out")
    after = evaluate_language_head(trained.head, network, synthetic_targets, paraphrases, wordllama, "held_out")
    assert (after["frames"], after["tasks"], after["sentences_per_task"]) == (24, 3, 2)
    assert after["mse"] < 0.5 * before["mse"] and after["cosine"] > 0.7, (before, after)
    assert after["ranking_top1"] == 1.0 and before["ranking_top1"] < 0.7, (before, after)


def test_the_contrastive_term_alone_ranks_the_right_task_first(shipped_policy, synthetic_targets, paraphrases,
                                                                wordllama):
    config = LanguageHeadConfig(regression_weight=0.0, contrastive_weight=1.0)
    trained = train_language_head(shipped_policy.network, synthetic_targets, paraphrases, wordllama, config, FAST)
    assert trained.history[-1]["contrastive"] < 0.3 * trained.history[0]["contrastive"], trained.history
    for split in ("seen", "held_out"):
        result = evaluate_language_head(trained.head, shipped_policy.network, synthetic_targets, paraphrases,
                                        wordllama, split)
        assert result["ranking_top1"] == 1.0 and result["ranking_chance"] == pytest.approx(1 / 3, abs=1e-3), result


def test_a_seed_repeats_a_run(shipped_policy, synthetic_targets, paraphrases, wordllama):
    settings = dataclasses.replace(FAST, steps=3, log_every=1)
    runs = [train_language_head(shipped_policy.network, synthetic_targets, paraphrases, wordllama, settings=settings)
            for _ in range(2)]
    other = train_language_head(shipped_policy.network, synthetic_targets, paraphrases, wordllama,
                                settings=dataclasses.replace(settings, seed=1))
    assert runs[0].history == runs[1].history != other.history
    weights = [run.head.state_dict() for run in (*runs, other)]
    assert all(torch.equal(weights[0][name], weights[1][name]) for name in weights[0])
    assert not all(torch.equal(weights[0][name], weights[2][name]) for name in weights[0])


def test_tasks_without_sentences_and_bad_settings_are_refused(shipped_policy, synthetic_targets, paraphrases,
                                                              wordllama):
    unknown = dataclasses.replace(synthetic_targets, tasks=["pick_and_lift", "my_task", "open_drawer"])
    with pytest.raises(ParaphraseError, match=r"no sentences for the tasks \['my_task'\]"):
        train_language_head(shipped_policy.network, unknown, paraphrases, wordllama, settings=FAST)
    with pytest.raises(ValueError, match="batch_size at least 2"):
        TrainSettings(batch_size=1)
    with pytest.raises(ValueError, match=r"task_index \(B,\)"):
        language_head_loss(torch.zeros(2, 6, 8), torch.zeros(2, 6, 8), torch.zeros(3, dtype=torch.long),
                           LanguageHeadConfig())
    assert np.array_equal(synthetic_targets.task_index[:3], [0, 1, 2])  # the fixture is left as it was
