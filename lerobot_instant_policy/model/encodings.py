"""NeRF-style sine/cosine encodings of relative positions (paper appendix A)."""

from __future__ import annotations

import functools
import math

import torch


@functools.lru_cache(maxsize=64)
def _frequencies(num_frequencies: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """``(num_frequencies, 1)``: ``2^k π``, built once per (size, dtype, device); never an inference tensor, so
    autograd may save it."""
    with torch.inference_mode(False):
        return ((2.0 ** torch.arange(num_frequencies, dtype=dtype, device=device)) * math.pi)[:, None]


def sinusoidal_encoding(vectors: torch.Tensor, num_frequencies: int = 10, include_input: bool = True) -> torch.Tensor:
    """Encode ``vectors (..., D)`` as ``sin(2^k π v), cos(2^k π v)`` for ``k = 0 … num_frequencies − 1``.

    Returns ``(..., D · 2 · num_frequencies [+ D])``: all sines, then all cosines, then (optionally) the raw
    vector. Units are metres, so the finest frequency ``2^9 π`` resolves millimetres.
    """
    frequencies = _frequencies(num_frequencies, vectors.dtype, vectors.device)
    angles = (vectors[..., None, :] * frequencies).flatten(-2)
    parts = [torch.sin(angles), torch.cos(angles)]
    if include_input:
        parts.append(vectors)
    return torch.cat(parts, dim=-1)


def encoding_dim(input_dim: int, num_frequencies: int, include_input: bool = True) -> int:
    """Width of :func:`sinusoidal_encoding`'s output for ``input_dim``-vectors."""
    return input_dim * (2 * num_frequencies + int(include_input))
