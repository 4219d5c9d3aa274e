"""The geometry encoder φ_e: two set-abstraction layers with NeRF-style relative-position encodings.

A cloud ``(B, P, 3)`` becomes ``M`` centroids with a feature each. Layer 1 samples ``S₁`` centroids by
farthest-point sampling, assigns every point to its nearest centroid, embeds ``enc(p − c)`` per point with an
MLP and max-pools per group. Layer 2 does the same on the ``S₁`` centroids (their features concatenated to the
encoding) to reach ``M = S₂`` nodes. Only relative positions enter the networks, so translating a cloud moves
the centroids and leaves the features unchanged; grouping and pooling are symmetric, so the point order does
not matter.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..config_io import config_from_dict
from ..geometry.rigid_torch import full_precision, invert_rigid, transform_points
from .encodings import encoding_dim, sinusoidal_encoding
from .point_ops import (
    farthest_point_sampling,
    gather_points,
    group_max,
    nearest_centroid,
)


@dataclass(frozen=True)
class GeometryEncoderConfig:
    """Sizes of the encoder. ``num_centroids[-1]`` is M, ``layer_widths[-1][-1]`` the node feature size."""

    num_centroids: tuple[int, ...] = (256, 16)
    layer_widths: tuple[tuple[int, ...], ...] = ((64, 128), (128, 256))
    num_frequencies: int = 10

    def __post_init__(self):
        object.__setattr__(self, "num_centroids", tuple(int(n) for n in self.num_centroids))
        object.__setattr__(self, "layer_widths", tuple(tuple(int(w) for w in widths) for widths in self.layer_widths))
        if len(self.num_centroids) != len(self.layer_widths) or not self.num_centroids:
            raise ValueError("num_centroids and layer_widths need one entry per set-abstraction layer")
        if any(b > a for a, b in zip(self.num_centroids, self.num_centroids[1:])) or min(self.num_centroids) < 1:
            raise ValueError(f"num_centroids must be positive and non-increasing, got {self.num_centroids}")
        if any(not widths or min(widths) < 1 for widths in self.layer_widths):
            raise ValueError(f"every layer needs positive widths, got {self.layer_widths}")
        if self.num_frequencies < 1:
            raise ValueError("num_frequencies must be at least 1")

    @property
    def num_nodes(self) -> int:
        return self.num_centroids[-1]

    @property
    def feature_dim(self) -> int:
        return self.layer_widths[-1][-1]

    def to_dict(self) -> dict:
        return {
            "num_centroids": list(self.num_centroids),
            "layer_widths": [list(w) for w in self.layer_widths],
            "num_frequencies": self.num_frequencies,
        }

    @classmethod
    def from_dict(cls, values: dict) -> GeometryEncoderConfig:
        return config_from_dict(cls, values)


ENCODER_PRESETS: dict[str, GeometryEncoderConfig] = {
    "small": GeometryEncoderConfig(),
    "paper": GeometryEncoderConfig(num_centroids=(256, 16), layer_widths=((128, 128, 256), (256, 512, 512))),
}


def encoder_preset(name: str) -> GeometryEncoderConfig:
    if name not in ENCODER_PRESETS:
        raise ValueError(f"unknown encoder preset {name!r}; known: {sorted(ENCODER_PRESETS)}")
    return ENCODER_PRESETS[name]


def mlp(widths: list[int]) -> nn.Sequential:
    """Linear → LayerNorm → GELU for every layer but the last, which is a plain Linear."""
    layers: list[nn.Module] = []
    for index, (width_in, width_out) in enumerate(zip(widths, widths[1:])):
        layers.append(nn.Linear(width_in, width_out))
        if index < len(widths) - 2:
            layers += [nn.LayerNorm(width_out), nn.GELU()]
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    """FPS centroids, hard nearest-centroid groups, a per-point MLP on ``[feature, enc(p − c)]``, max per group."""

    def __init__(self, num_centroids: int, in_features: int, widths: tuple[int, ...], num_frequencies: int):
        super().__init__()
        self.num_centroids = num_centroids
        self.num_frequencies = num_frequencies
        self.mlp = mlp([in_features + encoding_dim(3, num_frequencies), *widths])

    def forward(
        self, positions: torch.Tensor, features: torch.Tensor | None, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``positions (B, P, 3)``, ``features (B, P, C)`` or None → ``centroids (B, S, 3)``, ``(B, S, widths[-1])``."""
        centroid_index = farthest_point_sampling(positions, self.num_centroids, generator)
        centroids = gather_points(positions, centroid_index)
        groups = nearest_centroid(positions, centroids)
        relative = positions - gather_points(centroids, groups)
        inputs = sinusoidal_encoding(relative, self.num_frequencies)
        if features is not None:
            inputs = torch.cat([features, inputs], dim=-1)
        return centroids, group_max(self.mlp(inputs), groups, self.num_centroids)


class GeometryEncoder(nn.Module):
    """``points (B, P, 3)`` in any frame → ``node_positions (B, M, 3)`` in that frame, ``node_features (B, M, D)``."""

    def __init__(self, config: GeometryEncoderConfig | None = None):
        super().__init__()
        self.config = config or GeometryEncoderConfig()
        layers, in_features = [], 0
        for num_centroids, widths in zip(self.config.num_centroids, self.config.layer_widths):
            layers.append(SetAbstraction(num_centroids, in_features, widths, self.config.num_frequencies))
            in_features = widths[-1]
        self.layers = nn.ModuleList(layers)

    def forward(
        self, points: torch.Tensor, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Encode clouds.

        Args:
            points: ``(B, P, 3)`` float, ``P ≥ num_centroids[0]``, finite.
            generator: ``None`` (default) is the deterministic mode; a generator randomises the FPS starts
                (a training augmentation).
        """
        self.check_points(points)
        positions, features = points, None
        for layer in self.layers:
            positions, features = layer(positions, features, generator)
        return positions, features

    @full_precision()
    def encode(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The frozen encoder's reading of clouds ``(..., P, 3)`` (any frame, any leading shape) → positions
        ``(..., M, 3)`` in that frame, features ``(..., M, D)``: deterministic, without gradients and always in full
        precision (its farthest-point sampling picks the scene nodes, and its output is cached)."""
        leading = points.shape[:-2]
        with torch.no_grad():
            positions, features = self(points.reshape(-1, *points.shape[-2:]))
        return positions.view(*leading, *positions.shape[1:]), features.view(*leading, *features.shape[1:])

    def encode_in_frames(self, points_world: torch.Tensor, T_world_frame: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`encode` on clouds ``points_world (..., P, 3)`` expressed in their own frames ``T_world_frame
        (..., 4, 4)`` (an observation's EE frame) → positions in those frames ``(..., M, 3)``, features ``(..., M, D)``."""
        return self.encode(transform_points(invert_rigid(T_world_frame), points_world))

    def check_points(self, points: torch.Tensor) -> None:
        """Raise ``ValueError`` for a wrong shape or dtype, too few points, or NaN/inf coordinates."""
        if not isinstance(points, torch.Tensor) or points.ndim != 3 or points.shape[-1] != 3:
            shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
            raise ValueError(f"geometry encoder expects points of shape (B, P, 3), got {shape}")
        if not points.is_floating_point():
            raise ValueError(f"geometry encoder expects floating-point points, got {points.dtype}")
        if points.shape[1] < self.config.num_centroids[0]:
            raise ValueError(
                f"a cloud has {points.shape[1]} points but the encoder samples {self.config.num_centroids[0]} "
                "centroids; resample the cloud to more points"
            )
        if not torch.isfinite(points).all():
            raise ValueError("point cloud contains NaN or inf coordinates")
