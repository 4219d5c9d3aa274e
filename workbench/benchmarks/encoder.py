"""Speed of the geometry encoder on CPU (clouds of 2048 points per second) and of its farthest-point sampling."""

from __future__ import annotations

import statistics
import time

import torch

from lerobot_instant_policy.model.geometry_encoder import ENCODER_PRESETS, GeometryEncoder
from lerobot_instant_policy.model.point_ops import farthest_point_sampling, farthest_point_sampling_torch


@torch.no_grad()
def bench_encoder(batch_sizes: tuple[int, ...] = (1, 16), repeats: int = 5, num_points: int = 2048) -> dict:
    """Median clouds/s of the deterministic encoder forward pass per preset and batch size (random weights), and
    the first layer's farthest-point sampling (256 of ``num_points``) with the CPU ``fpsample`` path and with the
    torch loop, timed in the same run."""
    torch.manual_seed(0)
    result: dict = {"num_points": num_points, "torch_threads": torch.get_num_threads(), "repeats": repeats}
    for preset, config in ENCODER_PRESETS.items():
        encoder = GeometryEncoder(config).eval()
        for batch in batch_sizes:
            clouds = torch.randn(batch, num_points, 3) * 0.08
            encoder(clouds)
            seconds = []
            for _ in range(repeats):
                started = time.perf_counter()
                encoder(clouds)
                seconds.append(time.perf_counter() - started)
            median = statistics.median(seconds)
            result[f"{preset}_batch{batch}_clouds_per_s"] = round(batch / median, 1)
            result[f"{preset}_batch{batch}_ms_per_call"] = round(1000 * median, 2)
    for batch in batch_sizes:
        clouds = torch.randn(batch, num_points, 3) * 0.08
        start = (clouds - clouds.mean(dim=1, keepdim=True)).square().sum(-1).argmax(dim=1)
        fast = _median_seconds(lambda: farthest_point_sampling(clouds, 256), repeats)
        loop = _median_seconds(lambda: farthest_point_sampling_torch(clouds, 256, start), repeats)
        result[f"fps256_batch{batch}_ms"] = round(1000 * fast, 2)
        result[f"fps256_batch{batch}_torch_loop_ms"] = round(1000 * loop, 2)
        result[f"fps256_batch{batch}_speedup"] = round(loop / fast, 2)
    return result


def _median_seconds(call, repeats: int) -> float:
    """Median seconds of ``repeats`` calls of ``call`` after one untimed call."""
    call()
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - started)
    return statistics.median(seconds)
