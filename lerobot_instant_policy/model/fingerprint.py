"""A fingerprint of a frozen module: what caches keyed by an encoder's output (the frame encodings beside a training
dataset, the language head's text and geometry encoders) compare before they reuse what they stored."""

from __future__ import annotations

import hashlib
import json

import torch


def encoder_fingerprint(encoder: torch.nn.Module, config: dict) -> str:
    """SHA-256 of the encoder's architecture ``config`` and its weights (names, shapes, dtypes and bytes)."""
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode())
    for name, tensor in sorted(encoder.state_dict().items()):
        value = tensor.detach().to("cpu").contiguous()
        digest.update(f"{name}:{tuple(value.shape)}:{value.dtype}".encode())
        digest.update(value.numpy().tobytes())
    return digest.hexdigest()
