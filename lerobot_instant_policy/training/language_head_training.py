"""Training the language head on :class:`~.targets.LanguageTargets` and measuring it (paper appendix, modality
transfer: the bottleneck approximated from the current observation and a sentence, with a contrastive objective,
the trained network frozen).

The loss (:func:`language_head_loss`) is ``regression_weight · MSE + contrastive_weight · InfoNCE``:

* MSE of the predicted bottleneck ``(B, G, H)`` on the target: ψ reads the bottleneck's values, so they must be
  right, not only their direction.
* InfoNCE over the tasks of the batch, in the supervised-contrastive form (Khosla et al. 2020, ``L_out``): row ``i``'s
  prediction, flattened and unit-normalised, is scored against every row's target with ``cos / τ``, and the targets of
  rows of the *same task* are its positives: ``−log Σ_{j: task_j = task_i} exp(s_ij) / Σ_j exp(s_ij)``. What words
  must decide is the task; where in the scene it happens the observation decides. With one positive per row (the
  row's own target, CLIP's form) the other frames of the same task would be negatives and the term would push apart
  what the regression pulls together wherever the scene, not the sentence, tells two frames apart. A batch of one
  task gives the term nothing to do (it is 0). The paper names a contrastive objective without giving its form.

Batches (:func:`train_language_head`): a task drawn uniformly among the tasks with frames, one of its frames
uniformly, and one of its *seen* paraphrases uniformly, all from one ``torch.Generator`` seeded with
``TrainSettings.seed`` (the head's initial weights from the same seed), so a run is repeatable on one machine.
AdamW with a cosine-decayed learning rate and gradient clipping. What the frozen network makes of each frame's local
graph (:func:`~.language_head.current_local_graph`) and every sentence's vector are computed once before the loop.

:func:`evaluate_language_head` measures a head on targets with the sentences of one split (``held_out`` by default):
the MSE and cosine of its prediction with the task's own sentence, the MSE of the task's mean target on the same
frames (the error of knowing the task but not the scene), and ranking accuracy: per frame, the task whose sentence
gives the prediction nearest the frame's target (cosine), counted right only when the own task is strictly first.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from ..language.language_head import HeadBinding, LanguageHead, LanguageHeadConfig, current_local_graph
from ..language.paraphrases import Paraphrases
from ..language.text_encoder import TextEncoder
from ..model.instant_policy_network import InstantPolicyNetwork
from .language_targets import LanguageTargets, TargetsError


@dataclass
class TrainSettings:
    """How long and how the head trains: ``steps`` optimiser steps of ``batch_size`` rows, AdamW at ``lr`` (cosine
    decay to 0) with ``weight_decay``, gradients clipped to ``grad_clip_norm``; ``seed`` fixes the initial weights
    and every draw; a history entry every ``log_every`` steps; on ``device``."""

    steps: int = 1000
    batch_size: int = 32
    lr: float = 1e-3
    weight_decay: float = 0.01
    grad_clip_norm: float = 1.0
    seed: int = 0
    log_every: int = 50
    device: str = "cpu"

    def __post_init__(self):
        if self.steps < 1 or self.batch_size < 2 or self.log_every < 1:
            raise ValueError(f"steps and log_every must be at least 1 and batch_size at least 2, got {self}")


def language_head_loss(predicted: torch.Tensor, target: torch.Tensor, task_index: torch.Tensor,
                       config: LanguageHeadConfig) -> dict[str, torch.Tensor]:
    """The loss of the module docstring: ``predicted`` and ``target`` bottlenecks ``(B, G, H)``, each row's task
    ``task_index (B,)`` → ``loss``, ``regression`` (MSE) and ``contrastive`` (InfoNCE over tasks), scalars."""
    if predicted.shape != target.shape or predicted.ndim != 3 or task_index.shape != predicted.shape[:1]:
        raise ValueError(f"predicted and target must be (B, G, H) and task_index (B,), got {tuple(predicted.shape)}, "
                         f"{tuple(target.shape)}, {tuple(task_index.shape)}")
    regression = nn.functional.mse_loss(predicted, target)
    scores = nn.functional.normalize(predicted.flatten(1), dim=1) @ nn.functional.normalize(target.flatten(1), dim=1).T
    scores = scores / config.temperature  # (B, B): prediction i against target j
    positive = task_index[:, None] == task_index[None, :]
    contrastive = (torch.logsumexp(scores, 1) - torch.logsumexp(scores.masked_fill(~positive, -math.inf), 1)).mean()
    loss = config.regression_weight * regression + config.contrastive_weight * contrastive
    return {"loss": loss, "regression": regression, "contrastive": contrastive}


@dataclass
class SentenceTable:
    """The sentences of one split of every task of a targets set, encoded once: ``vectors (S, E)`` grouped by task,
    task ``t``'s at rows ``offsets[t] … offsets[t] + counts[t] − 1``."""

    vectors: torch.Tensor
    offsets: torch.Tensor
    counts: torch.Tensor

    @classmethod
    def encode(cls, paraphrases: Paraphrases, tasks: list[str], text_encoder: TextEncoder, split: str,
               device: torch.device | str = "cpu") -> SentenceTable:
        sentences = [paraphrases[task].split(split) for task in tasks]
        counts = torch.tensor([len(group) for group in sentences])
        vectors = torch.from_numpy(text_encoder.encode([sentence for group in sentences for sentence in group]))
        return cls(vectors.to(device), (torch.cumsum(counts, 0) - counts).to(device), counts.to(device))

    def draw(self, task_index: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """One of each row's task's sentences, uniformly: ``task_index (B,)`` → ``(B, E)``."""
        uniform = torch.rand(len(task_index), generator=generator).to(self.counts.device)
        choice = (uniform * self.counts[task_index]).long().clamp(max=self.counts[task_index] - 1)
        return self.vectors[self.offsets[task_index] + choice]

    def kth(self, k: int) -> torch.Tensor:
        """Every task's ``k``-th sentence (modulo its count): ``(T, E)``."""
        return self.vectors[self.offsets + k % self.counts]


@dataclass
class HeadInputs:
    """A targets set on a device with the frozen network's reading of each frame (:func:`current_local_graph`):
    ``scene_positions (F, M, 3)``, ``scene_nodes (F, M, H)``, ``gripper_nodes (F, G, H)``, ``bottleneck (F, G, H)``,
    ``task_index (F,)``."""

    scene_positions: torch.Tensor
    scene_nodes: torch.Tensor
    gripper_nodes: torch.Tensor
    bottleneck: torch.Tensor
    task_index: torch.Tensor

    @classmethod
    def read(cls, network: InstantPolicyNetwork, targets: LanguageTargets, device: torch.device | str,
             chunk: int = 512) -> HeadInputs:
        if targets.num_frames == 0:
            raise TargetsError("the targets hold no frames")
        network_device = next(network.parameters()).device
        positions = torch.from_numpy(targets.scene_positions)
        scene_nodes, gripper_nodes = [], []
        for start in range(0, targets.num_frames, chunk):
            rows = slice(start, start + chunk)
            scene, gripper = current_local_graph(
                network, positions[rows].to(network_device),
                torch.from_numpy(targets.scene_features[rows]).to(network_device),
                torch.from_numpy(targets.gripper_open[rows]).to(network_device))
            scene_nodes.append(scene.to(device))
            gripper_nodes.append(gripper.to(device))
        return cls(positions.to(device), torch.cat(scene_nodes), torch.cat(gripper_nodes),
                   torch.from_numpy(targets.bottleneck).to(device), torch.from_numpy(targets.task_index).to(device))

    def predict(self, head: LanguageHead, rows: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        """``head`` on frames ``rows (B,)`` with sentence vectors ``text (B, E)`` → ``(B, G, H)``."""
        return head(self.scene_positions[rows], self.scene_nodes[rows], self.gripper_nodes[rows], text)


@dataclass
class TrainedHead:
    """A trained head and its ``history``: the mean losses over each ``log_every`` steps (``step`` is the last)."""

    head: LanguageHead
    history: list[dict]


def train_language_head(network: InstantPolicyNetwork, targets: LanguageTargets, paraphrases: Paraphrases,
                        text_encoder: TextEncoder, config: LanguageHeadConfig | None = None,
                        settings: TrainSettings | None = None,
                        on_log: Callable[[dict], None] | None = None) -> TrainedHead:
    """Train a new head for ``network`` and ``text_encoder`` on ``targets`` with the seen paraphrases (module
    docstring); ``on_log`` receives each history entry as it is made."""
    config, settings = config or LanguageHeadConfig(), settings or TrainSettings()
    device = torch.device(settings.device)
    paraphrases.check_tasks(targets.tasks)
    frames_per_task = np.bincount(targets.task_index, minlength=len(targets.tasks))
    tasks_with_frames = torch.from_numpy(np.flatnonzero(frames_per_task)).to(device)
    inputs = HeadInputs.read(network, targets, device)
    sentences = SentenceTable.encode(paraphrases, targets.tasks, text_encoder, "seen", device)
    order = torch.argsort(inputs.task_index, stable=True)  # frames grouped by task
    counts = torch.from_numpy(frames_per_task).to(device)
    offsets = torch.cumsum(counts, 0) - counts
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(settings.seed)
        head = LanguageHead(config, HeadBinding.of(network, text_encoder)).to(device)
    generator = torch.Generator().manual_seed(settings.seed)
    optimizer = torch.optim.AdamW(head.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, settings.steps)
    head.train()
    history, window = [], []
    for step in range(1, settings.steps + 1):
        draw = torch.randint(len(tasks_with_frames), (settings.batch_size,), generator=generator).to(device)
        task = tasks_with_frames[draw]
        within = (torch.rand(settings.batch_size, generator=generator).to(device) * counts[task]).long()
        rows = order[offsets[task] + within.clamp(max=counts[task] - 1)]
        predicted = inputs.predict(head, rows, sentences.draw(task, generator))
        losses = language_head_loss(predicted, inputs.bottleneck[rows], task, config)
        optimizer.zero_grad()
        losses["loss"].backward()
        nn.utils.clip_grad_norm_(head.parameters(), settings.grad_clip_norm)
        optimizer.step()
        scheduler.step()
        window.append({name: float(value.detach()) for name, value in losses.items()})
        if step % settings.log_every == 0 or step == settings.steps:
            entry = {"step": step, **{name: float(np.mean([row[name] for row in window])) for name in window[0]}}
            history.append(entry)
            window = []
            if on_log is not None:
                on_log(entry)
    return TrainedHead(head.eval(), history)


@torch.no_grad()
def evaluate_language_head(head: LanguageHead, network: InstantPolicyNetwork, targets: LanguageTargets,
                           paraphrases: Paraphrases, text_encoder: TextEncoder, split: str = "held_out",
                           chunk: int = 64) -> dict:
    """The figures of the module docstring on every frame of ``targets`` with every sentence of ``split`` (the
    ``k``-th sentence of every task is a candidate of round ``k``; the figures average over rounds and frames)."""
    head.check_binding(network, text_encoder)
    device = head.gripper_keypoints.device
    inputs = HeadInputs.read(network, targets, device)
    sentences = SentenceTable.encode(paraphrases, targets.tasks, text_encoder, split, device)
    present = torch.from_numpy(np.flatnonzero(np.bincount(targets.task_index, minlength=len(targets.tasks)))).to(device)
    num_tasks, frames = len(present), targets.num_frames
    squared, cosine, correct = 0.0, 0.0, 0
    rounds = int(sentences.counts[present].max())
    for k in range(rounds):
        candidates = sentences.kth(k)[present]  # (T', E), the tasks that have frames
        for start in range(0, frames, chunk):
            rows = torch.arange(start, min(start + chunk, frames), device=device)
            own = torch.searchsorted(present, inputs.task_index[rows])  # each row's task among the candidates
            target = inputs.bottleneck[rows]
            predicted = inputs.predict(head, rows.repeat_interleave(num_tasks), candidates.repeat(len(rows), 1))
            predicted = predicted.view(len(rows), num_tasks, *target.shape[1:])
            similarity = nn.functional.cosine_similarity(predicted.flatten(2), target.flatten(1)[:, None], dim=-1)
            own_prediction = predicted[torch.arange(len(rows), device=device), own]
            squared += float((own_prediction - target).square().mean(dim=(1, 2)).sum())
            cosine += float(similarity.gather(1, own[:, None]).sum())
            others = similarity.scatter(1, own[:, None], -math.inf).amax(1)
            correct += int((similarity.gather(1, own[:, None])[:, 0] > others).sum())
    sums = torch.zeros(len(targets.tasks), *inputs.bottleneck.shape[1:], device=device).index_add_(
        0, inputs.task_index, inputs.bottleneck)
    task_means = sums / torch.bincount(inputs.task_index, minlength=len(targets.tasks)).clamp(min=1)[:, None, None]
    pairs = rounds * frames
    return {
        "split": split, "frames": frames, "tasks": num_tasks, "sentences_per_task": rounds,
        "mse": round(squared / pairs, 5),
        "mse_task_mean": round(float((inputs.bottleneck - task_means[inputs.task_index]).square().mean()), 5),
        "cosine": round(cosine / pairs, 4),
        "ranking_top1": round(correct / pairs, 4), "ranking_chance": round(1.0 / num_tasks, 4),
    }
