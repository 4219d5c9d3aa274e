"""Occupancy pretraining head (paper appendix A) and the weights file format of the geometry encoder.

The decoder ψ_e reads one node's feature and ``enc(q − p_node)`` and predicts whether the query ``q`` lies on
the object surface. Every query is decoded by its nearest node only, so each node reconstructs its local part.

Weights file: ``NAME.safetensors`` holds ``encoder.*`` and ``decoder.*`` tensors; ``NAME.json`` beside it holds
``{"encoder": <GeometryEncoderConfig>, "decoder": <OccupancyDecoderConfig>, "metrics": …, "pretraining": …}``.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file
from torch import nn

from .encodings import encoding_dim, sinusoidal_encoding
from .geometry_encoder import GeometryEncoder, GeometryEncoderConfig, encoder_preset
from .point_ops import gather_points, nearest_centroid


@dataclass(frozen=True)
class OccupancyDecoderConfig:
    hidden_dim: int = 128
    num_layers: int = 8

    def __post_init__(self):
        if self.hidden_dim < 1 or self.num_layers < 2:
            raise ValueError("the decoder needs hidden_dim ≥ 1 and num_layers ≥ 2")


DECODER_PRESETS = {"small": OccupancyDecoderConfig(), "paper": OccupancyDecoderConfig(hidden_dim=512)}


class ResidualBlock(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.linear = nn.Linear(width, width)

    def forward(self, hidden: torch.Tensor) -> torch.Tensor:
        return hidden + self.linear(nn.functional.gelu(self.norm(hidden)))


class OccupancyDecoder(nn.Module):
    """``node_features (..., D)``, ``offsets (..., 3)`` (query − node, m) → on-surface logits ``(...)``.

    An input projection, ``num_layers − 2`` residual blocks and an output layer: ``num_layers`` linear layers.
    """

    def __init__(self, feature_dim: int, config: OccupancyDecoderConfig, num_frequencies: int = 10):
        super().__init__()
        self.config = config
        self.num_frequencies = num_frequencies
        self.input = nn.Linear(feature_dim + encoding_dim(3, num_frequencies), config.hidden_dim)
        self.blocks = nn.Sequential(*[ResidualBlock(config.hidden_dim) for _ in range(config.num_layers - 2)])
        self.output = nn.Sequential(nn.LayerNorm(config.hidden_dim), nn.GELU(), nn.Linear(config.hidden_dim, 1))

    def forward(self, node_features: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        hidden = self.input(torch.cat([node_features, sinusoidal_encoding(offsets, self.num_frequencies)], dim=-1))
        return self.output(self.blocks(hidden)).squeeze(-1)


class OccupancyNetwork(nn.Module):
    """Encoder plus decoder: ``points (B, P, 3)``, ``queries (B, Q, 3)`` → on-surface logits ``(B, Q)``."""

    def __init__(self, encoder_config: GeometryEncoderConfig, decoder_config: OccupancyDecoderConfig):
        super().__init__()
        self.encoder = GeometryEncoder(encoder_config)
        self.decoder = OccupancyDecoder(encoder_config.feature_dim, decoder_config, encoder_config.num_frequencies)

    @classmethod
    def from_preset(cls, name: str) -> OccupancyNetwork:
        return cls(encoder_preset(name), DECODER_PRESETS[name])

    def forward(
        self, points: torch.Tensor, queries: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        node_positions, node_features = self.encoder(points, generator)
        return self.decode(node_positions, node_features, queries)

    def decode(self, node_positions: torch.Tensor, node_features: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """Decode each query ``(B, Q, 3)`` with its nearest node → logits ``(B, Q)``."""
        nearest = nearest_centroid(queries, node_positions)
        offsets = queries - gather_points(node_positions, nearest)
        return self.decoder(gather_points(node_features, nearest), offsets)


def save_occupancy_network(network: OccupancyNetwork, path: str | Path, **extra: dict) -> None:
    """Write ``path`` (.safetensors) and its JSON sidecar; ``extra`` entries (metrics, pretraining) go to the JSON."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {key: value.detach().cpu().contiguous() for key, value in network.state_dict().items()}
    save_file(tensors, str(path))
    sidecar = {
        "encoder": network.encoder.config.to_dict(),
        "decoder": dataclasses.asdict(network.decoder.config),
        **extra,
    }
    sidecar_path(path).write_text(json.dumps(sidecar, indent=2) + "\n")


def sidecar_path(path: str | Path) -> Path:
    return Path(path).with_suffix(".json")


def read_sidecar(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no weights file at {path}")
    if not sidecar_path(path).is_file():
        raise FileNotFoundError(f"weights {path} have no config file {sidecar_path(path)} beside them")
    return json.loads(sidecar_path(path).read_text())


def load_occupancy_network(path: str | Path, expected: GeometryEncoderConfig | None = None) -> OccupancyNetwork:
    """Load a network written by :func:`save_occupancy_network`; refuse it if its encoder is not ``expected``."""
    sidecar = read_sidecar(path)
    encoder_config = GeometryEncoderConfig.from_dict(sidecar["encoder"])
    _check_expected(path, encoder_config, expected)
    network = OccupancyNetwork(encoder_config, OccupancyDecoderConfig(**sidecar["decoder"]))
    _load_strict(network, load_file(str(path)), path)
    return network


def load_geometry_encoder(path: str | Path, expected: GeometryEncoderConfig | None = None) -> GeometryEncoder:
    """Only the encoder of a weights file (the decoder is not needed by the policy)."""
    encoder_config = GeometryEncoderConfig.from_dict(read_sidecar(path)["encoder"])
    _check_expected(path, encoder_config, expected)
    encoder = GeometryEncoder(encoder_config)
    _load_encoder_tensors(encoder, path)
    return encoder


def load_encoder_weights(encoder: GeometryEncoder, path: str | Path) -> None:
    """Load the encoder of a weights file into ``encoder``; ``ValueError`` when the file was trained for another
    architecture than ``encoder.config``."""
    _check_expected(path, GeometryEncoderConfig.from_dict(read_sidecar(path)["encoder"]), encoder.config)
    _load_encoder_tensors(encoder, path)


def _load_encoder_tensors(encoder: GeometryEncoder, path: str | Path) -> None:
    prefix = "encoder."
    tensors = {key[len(prefix) :]: value for key, value in load_file(str(path)).items() if key.startswith(prefix)}
    _load_strict(encoder, tensors, path)


def _load_strict(module: nn.Module, tensors: dict[str, torch.Tensor], path) -> None:
    try:
        module.load_state_dict(tensors, strict=True)
    except RuntimeError as error:
        raise ValueError(f"weights {path} do not match the config in {sidecar_path(path)}: {error}") from error


def _check_expected(path, found: GeometryEncoderConfig, expected: GeometryEncoderConfig | None) -> None:
    if expected is not None and found != expected:
        raise ValueError(
            f"encoder weights {path} were trained for config {found.to_dict()}, "
            f"which does not match the requested {expected.to_dict()}"
        )
