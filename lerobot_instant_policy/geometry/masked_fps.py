"""Farthest-point sampling of a batch of clouds of different sizes, in plain torch (any device, one code path).

Each cloud is a padded ``(N, 3)`` row with a ``valid (N,)`` mask. Greedy FPS picks, from a given start, the valid
point farthest from those already chosen, until it has ``S`` of them. A cloud with fewer than ``S`` valid points
yields every valid point once (in FPS order) followed by repeats of that order, ``chosen[j] = chosen[j mod count]``.
Every cloud runs independently of the others in the batch, so a batch gives what each cloud gives alone.
"""

from __future__ import annotations

import torch


def masked_farthest_point_sampling(
    points: torch.Tensor, valid: torch.Tensor, num_samples: int, start: torch.Tensor
) -> torch.Tensor:
    """Greedy FPS restricted to the valid points of each cloud.

    Args:
        points: ``(B, N, 3)``.
        valid: ``(B, N)`` bool; a cloud with no valid point gives index 0 everywhere (the caller flags it).
        num_samples: ``S ≥ 1``.
        start: ``(B,)`` int64 index of each cloud's first sample; it must be a valid point.

    Returns:
        ``(B, S)`` int64 indices into ``N``.
    """
    batch, num_points, _ = points.shape
    device = points.device
    steps = min(num_samples, num_points)
    chosen = torch.empty(batch, steps, dtype=torch.long, device=device)
    # invalid points sit at −1 so that argmax never picks one while a valid point (≥ 0) remains
    min_sq_dist = torch.where(valid, torch.inf, -1.0).to(points.dtype)
    batch_index = torch.arange(batch, device=device)
    coords = points.permute(2, 0, 1).contiguous()  # (3, B, N): one contiguous plane per axis
    sq_dist, term = torch.empty_like(min_sq_dist), torch.empty_like(min_sq_dist)
    farthest = start
    for sample in range(steps):
        chosen[:, sample] = farthest
        centre = points[batch_index, farthest]  # (B, 3)
        # squared distances to the new sample, in place (the loop is bound by allocations on the CPU)
        torch.sub(coords[0], centre[:, 0:1], out=sq_dist).square_()
        for axis in (1, 2):
            sq_dist.add_(torch.sub(coords[axis], centre[:, axis : axis + 1], out=term).square_())
        torch.minimum(min_sq_dist, sq_dist, out=min_sq_dist)
        min_sq_dist[batch_index, farthest] = -0.5  # chosen: below every unchosen valid point, above invalid ones
        farthest = min_sq_dist.argmax(dim=1)
    count = valid.sum(dim=1).clamp(min=1)
    cyclic = torch.arange(num_samples, device=device)[None, :] % count[:, None]
    return torch.gather(chosen, 1, cyclic)
