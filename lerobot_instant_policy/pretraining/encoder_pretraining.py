"""Occupancy pretraining of the geometry encoder: train, resume, evaluate on held-out objects.

Training scenes use the object library's training split, evaluation scenes its held-out split. Every batch is
rotated by a random rotation about its cloud's mean and shifted (the policy sees clouds in the end-effector
frame, at any orientation); labels do not change under rigid motions. Progress is checkpointed to
``OUT.resume.pt`` (weights, optimiser, schedule, step, random state, elapsed time), so a killed run continues where
it stopped; the final weights go to ``OUT`` (.safetensors) with a JSON of config, metrics and timing.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import roma
import torch
from tqdm import tqdm

from ..model.geometry_encoder import GeometryEncoderConfig, encoder_preset
from ..model.occupancy import OccupancyNetwork, load_occupancy_network, save_occupancy_network
from .occupancy_data import OccupancyDataConfig, OccupancySet, cached_occupancy_set

EVAL_SEED = 1


@dataclass
class PretrainConfig:
    """``lerobot-ip-pretrain-encoder``'s settings; the defaults are the run that made the shipped weights."""

    preset: str = "small"
    steps: int = 2000
    batch_size: int = 16
    queries_per_cloud: int = 1024
    lr: float = 1e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    train_scenes: int = 2000
    eval_scenes: int = 200
    seed: int = 0
    workers: int = 1
    cache_dir: str = "outputs/occupancy_cache"
    checkpoint_every: int = 200
    random_fps_start: bool = True
    device: str = "cpu"
    data: OccupancyDataConfig = field(default_factory=OccupancyDataConfig)

    def validate(self) -> None:
        encoder_preset(self.preset)
        for name in (
            "steps",
            "batch_size",
            "queries_per_cloud",
            "train_scenes",
            "eval_scenes",
            "workers",
            "checkpoint_every",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.queries_per_cloud > self.data.num_queries:
            raise ValueError(f"queries_per_cloud ({self.queries_per_cloud}) exceeds the stored {self.data.num_queries}")


def resume_path(out: Path) -> Path:
    return out.with_name(out.stem + ".resume.pt")


def random_rigid_motion(
    points: torch.Tensor, queries: torch.Tensor, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotate each sample's ``points (B, P, 3)`` and ``queries (B, Q, 3)`` about the cloud mean, then shift by ≤ 0.5 m."""
    batch = points.shape[0]
    rotation = roma.random_rotmat(batch, generator=generator).to(points)
    center = points.mean(dim=1, keepdim=True)
    shift = (torch.rand(batch, 1, 3, generator=generator) - 0.5).to(points)

    def move(values: torch.Tensor) -> torch.Tensor:
        return (values - center) @ rotation.transpose(1, 2) + center + shift

    return move(points), move(queries)


def classification_metrics(logits: torch.Tensor, labels: torch.Tensor) -> dict[str, float]:
    """Balanced accuracy, IoU and rates of the on-surface label at probability 0.5."""
    predicted, labels = logits > 0, labels.bool()
    true_pos = (predicted & labels).sum().item()
    false_pos = (predicted & ~labels).sum().item()
    false_neg = (~predicted & labels).sum().item()
    true_neg = (~predicted & ~labels).sum().item()
    tpr = true_pos / max(true_pos + false_neg, 1)
    tnr = true_neg / max(true_neg + false_pos, 1)
    return {
        "balanced_accuracy": (tpr + tnr) / 2,
        "iou": true_pos / max(true_pos + false_pos + false_neg, 1),
        "true_positive_rate": tpr,
        "true_negative_rate": tnr,
        "accuracy": (true_pos + true_neg) / max(labels.numel(), 1),
        "positive_fraction": labels.float().mean().item(),
    }


@torch.no_grad()
def evaluate(network: OccupancyNetwork, data: OccupancySet, batch_size: int = 16, device: str = "cpu") -> dict:
    """Metrics over every query of ``data``; clouds are rotated by fixed random rotations (seed ``EVAL_SEED``)."""
    network.eval()
    generator = torch.Generator().manual_seed(EVAL_SEED)
    all_logits, all_labels = [], []
    for begin in range(0, len(data), batch_size):
        points = torch.from_numpy(data.points[begin : begin + batch_size])
        queries = torch.from_numpy(data.queries[begin : begin + batch_size])
        points, queries = random_rigid_motion(points, queries, generator)
        all_logits.append(network(points.to(device), queries.to(device)).cpu())
        all_labels.append(torch.from_numpy(data.labels[begin : begin + batch_size]))
    metrics = classification_metrics(torch.cat(all_logits), torch.cat(all_labels))
    return {**metrics, "num_scenes": len(data), "num_queries": int(data.labels.size)}


def evaluate_weights(weights: Path, config: PretrainConfig, expected: GeometryEncoderConfig | None = None) -> dict:
    """:func:`evaluate` of the occupancy network in the weights file ``weights`` on the held-out set of ``config``;
    ``expected``: refuse (``ValueError``) weights of another encoder configuration."""
    network = load_occupancy_network(weights, expected)
    _, eval_set = load_sets(config, train=False)
    return evaluate(network, eval_set)


def load_sets(config: PretrainConfig, train: bool = True) -> tuple[OccupancySet | None, OccupancySet]:
    """The (training, held-out) occupancy sets, generated once and cached under ``config.cache_dir``."""
    cache = Path(config.cache_dir)
    train_set = (
        cached_occupancy_set(cache, config.train_scenes, config.seed, "train", config.data, config.workers)
        if train
        else None
    )
    eval_set = cached_occupancy_set(
        cache, config.eval_scenes, config.seed + 1000, "held_out", config.data, config.workers
    )
    return train_set, eval_set


def pretrain(config: PretrainConfig, out: Path, resume: bool = True, progress: bool = True) -> dict:
    """Train ``config.steps`` steps (continuing ``OUT.resume.pt`` when ``resume``), evaluate, write ``out``."""
    config.validate()
    out = Path(out)
    train_set, eval_set = load_sets(config)
    torch.manual_seed(config.seed)
    network = OccupancyNetwork.from_preset(config.preset).to(config.device)
    optimizer = torch.optim.AdamW(network.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, _warmup_cosine(config.warmup_steps, config.steps))
    generator = torch.Generator().manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    step, elapsed = 0, 0.0
    state_file = resume_path(out)
    if resume and state_file.is_file():
        state = torch.load(state_file, weights_only=True)
        if state["config"] != dataclasses.asdict(config):
            raise ValueError(f"{state_file} was written by a run with other settings; pass --no-resume to start over")
        network.load_state_dict(state["network"])
        optimizer.load_state_dict(state["optimizer"])
        schedule.load_state_dict(state["schedule"])
        generator.set_state(state["generator"])
        rng.bit_generator.state = state["rng"]
        step, elapsed = state["step"], state["elapsed"]
    bar = tqdm(total=config.steps, initial=step, desc="occupancy pretraining", disable=not progress)
    running = None
    network.train()
    while step < config.steps:
        started = time.perf_counter()
        loss, metrics = _train_step(network, optimizer, train_set, config, generator, rng)
        schedule.step()
        step += 1
        elapsed += time.perf_counter() - started
        running = loss if running is None else 0.98 * running + 0.02 * loss
        bar.update(1)
        bar.set_postfix(loss=f"{running:.4f}", bal_acc=f"{metrics['balanced_accuracy']:.3f}")
        if step % config.checkpoint_every == 0 or step == config.steps:
            _save_state(state_file, config, network, optimizer, schedule, generator, rng, step, elapsed)
    bar.close()
    metrics = evaluate(network, eval_set, config.batch_size, config.device)
    pretraining = {
        "preset": config.preset,
        "steps": config.steps,
        "train_seconds": round(elapsed, 1),
        "device": config.device,
        "torch_threads": torch.get_num_threads(),
        "final_train_loss": running,
        "config": dataclasses.asdict(config),
    }
    save_occupancy_network(network.cpu(), out, metrics={"held_out": metrics}, pretraining=pretraining)
    return {"held_out": metrics, "pretraining": pretraining}


def _train_step(network, optimizer, data: OccupancySet, config: PretrainConfig, generator, rng) -> tuple[float, dict]:
    scenes = rng.choice(len(data), size=config.batch_size, replace=False)
    query_index = np.stack(
        [rng.choice(config.data.num_queries, config.queries_per_cloud, replace=False) for _ in scenes]
    )
    points = torch.from_numpy(data.points[scenes])
    queries = torch.from_numpy(np.take_along_axis(data.queries[scenes], query_index[..., None], axis=1))
    labels = torch.from_numpy(np.take_along_axis(data.labels[scenes], query_index, axis=1)).float()
    points, queries = random_rigid_motion(points, queries, generator)
    fps_generator = generator if config.random_fps_start else None
    logits = network(points.to(config.device), queries.to(config.device), fps_generator)
    loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, labels.to(config.device))
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(network.parameters(), 1.0)
    optimizer.step()
    return loss.item(), classification_metrics(logits.detach().cpu(), labels)


def _warmup_cosine(warmup_steps: int, total_steps: int):
    def factor(step: int) -> float:
        if step < warmup_steps:
            return (step + 1) / warmup_steps
        progress = (step - warmup_steps) / max(total_steps - warmup_steps, 1)
        return 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))

    return factor


def _save_state(path: Path, config, network, optimizer, schedule, generator, rng, step: int, elapsed: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "config": dataclasses.asdict(config),
        "network": network.state_dict(),
        "optimizer": optimizer.state_dict(),
        "schedule": schedule.state_dict(),
        "generator": generator.get_state(),
        "rng": rng.bit_generator.state,
        "step": step,
        "elapsed": elapsed,
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    tmp.replace(path)
