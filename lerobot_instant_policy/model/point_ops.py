"""Farthest-point sampling and nearest-centroid grouping in plain torch (no pyg-lib / torch-cluster).

Every operation works per cloud on a batch ``(B, P, 3)``, so its cost grows linearly with the batch. On CPU,
float32 farthest-point sampling runs the same exact greedy algorithm in ``fpsample`` (C++), faster than the torch
loop (docs/benchmarks.md) and with the same indices (tested); the torch loop serves other dtypes and devices.
"""

from __future__ import annotations

import warnings

import fpsample
import numpy as np
import torch


def farthest_point_sampling(
    points: torch.Tensor, num_samples: int, generator: torch.Generator | None = None
) -> torch.Tensor:
    """Greedy farthest-point sampling.

    Args:
        points: ``(B, P, 3)``.
        num_samples: ``S ≤ P``.
        generator: ``None`` selects the deterministic start, the point farthest from the cloud's mean, which makes
            the result independent of point order and of translations. A generator draws a random start per cloud.

    Returns:
        ``(B, S)`` int64 indices into ``P``; the first is the start, each next one maximises the distance to the
        already chosen set.
    """
    batch, num_points, _ = points.shape
    if num_samples > num_points:
        raise ValueError(f"cannot sample {num_samples} points from a cloud of {num_points}")
    if generator is None:
        start = (points - points.mean(dim=1, keepdim=True)).square().sum(-1).argmax(dim=1)
    else:
        start = torch.randint(num_points, (batch,), generator=generator, device=generator.device).to(points.device)
    if points.device.type == "cpu" and points.dtype == torch.float32:
        clouds = points.detach().contiguous().numpy()
        return torch.from_numpy(
            np.stack([fpsample.fps_sampling(cloud, num_samples, start_idx=int(first)) for cloud, first in zip(clouds, start)])
        ).long()
    return farthest_point_sampling_torch(points, num_samples, start)


def farthest_point_sampling_torch(points: torch.Tensor, num_samples: int, start: torch.Tensor) -> torch.Tensor:
    """The greedy farthest-point loop of :func:`farthest_point_sampling` in plain torch (any dtype and device).

    Args:
        points: ``(B, P, 3)``.
        num_samples: ``S ≤ P``.
        start: ``(B,)`` int64 index of each cloud's first sample.

    Returns:
        ``(B, S)`` int64 indices into ``P``, the same as ``fpsample``'s for the same starts.
    """
    batch, num_points, _ = points.shape
    chosen = torch.empty(batch, num_samples, dtype=torch.long, device=points.device)
    min_sq_dist = torch.full((batch, num_points), float("inf"), dtype=points.dtype, device=points.device)
    batch_index = torch.arange(batch, device=points.device)
    farthest = start
    for sample in range(num_samples):
        chosen[:, sample] = farthest
        sq_dist = (points - points[batch_index, farthest][:, None]).square().sum(-1)
        min_sq_dist = torch.minimum(min_sq_dist, sq_dist)
        farthest = min_sq_dist.argmax(dim=1)
    return chosen


def nearest_centroid(points: torch.Tensor, centroids: torch.Tensor) -> torch.Tensor:
    """Index of the nearest centroid of every point: ``points (B, P, 3)``, ``centroids (B, S, 3)`` → ``(B, P)``.

    Exact Euclidean distances (no matrix-product shortcut), so batched and single-cloud calls agree.
    """
    distances = torch.cdist(points, centroids, compute_mode="donot_use_mm_for_euclid_dist")
    return distances.argmin(dim=-1)


def gather_points(values: torch.Tensor, indices: torch.Tensor) -> torch.Tensor:
    """``values (B, P, C)`` gathered at ``indices (B, S)`` → ``(B, S, C)``."""
    return torch.gather(values, 1, indices[..., None].expand(-1, -1, values.shape[-1]))


def group_max(values: torch.Tensor, groups: torch.Tensor, num_groups: int) -> torch.Tensor:
    """Per-group maximum: ``values (B, P, C)``, ``groups (B, P)`` in ``[0, num_groups)`` → ``(B, num_groups, C)``.

    An empty group (possible only when a cloud repeats points) gets zeros. The groups of all clouds are reduced as rows
    of one ``(B · num_groups, C)`` table (``index_reduce``: several times faster than a ``scatter_reduce`` along the
    points, with the same values and gradients).
    """
    batch, _, channels = values.shape
    rows = (groups + num_groups * torch.arange(batch, device=groups.device)[:, None]).flatten()
    pooled = values.new_zeros(batch * num_groups, channels)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="index_reduce", category=UserWarning)  # "in beta" (stable since 2.0)
        pooled = pooled.index_reduce(0, rows, values.reshape(-1, channels), "amax", include_self=False)
    return pooled.view(batch, num_groups, channels)
