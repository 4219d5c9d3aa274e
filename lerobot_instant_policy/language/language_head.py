"""The language head (paper appendix, modality transfer): the current observation's local graph and a sentence →
an estimate of Instant Policy's bottleneck, so that the trained ψ acts on a task said in words.

The bottleneck is φ's output at the current gripper nodes, ``(B, G, H)``
(:attr:`~..model.instant_policy_network.InstantPolicyContext.current_gripper_features`): everything ψ reads of the
demonstrations and the live observation. The head replaces σ-then-φ on demonstrations by a graph transformer on the
current local graph with the sentence as one more node, as the paper describes ("a graph transformer architecture,
similar to the one used to learn σ, [with] f_lang as an additional type of node"):

* scene nodes: the ``M`` encoder centroids of the live cloud in the current EE frame, ``scene_positions (B, M, 3)``,
  with the trained network's projection of their features (``scene_projection``: ``(B, M, H)``);
* gripper nodes: the ``G`` keypoints in the EE frame, with σ's output on the current local graph (what the trained
  network feeds φ, :func:`current_local_graph`): ``(B, G, H)``;
* one language node at the EE origin: the sentence vector ``(B, E)`` through an MLP to ``H``.

Edges: the local graph's (scene → scene, scene → gripper, gripper → gripper; attributes ``enc(p_dst − p_src)``
as σ's) and language → every scene node and every gripper node (attribute ``enc(p_dst)``, the node's position seen
from the EE origin). The layers are the project's :class:`~..model.graph_transformer.HeteroGraphTransformer`
(paper eq. 3) in its dense layout; the last keeps only the edges into the gripper nodes, whose features are the
predicted bottleneck. Every input is in the current EE frame, so where the world is does not change the output.

The trained network is frozen and read only (its scene projection and σ, through
:func:`current_local_graph`); the head owns its own weights. :class:`HeadBinding` records which network (a SHA-256
of its weights) and which text encoder (:attr:`~.text_encoder.TextEncoder.fingerprint`) a head was made for, and
:meth:`LanguageHead.check_binding` refuses others. Saved as ``config.json`` (the head's config and binding) and
``model.safetensors`` (its weights), no pickle.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors.torch import load_model, save_model
from torch import nn

from ..config_io import config_from_dict
from ..model.dense_graphs import dense_local_masks, dense_position_attr
from ..model.fingerprint import encoder_fingerprint
from ..model.graph import (
    GRIPPER,
    GRIPPER_TO_GRIPPER,
    SCENE,
    SCENE_TO_GRIPPER,
    SCENE_TO_SCENE,
    local_edge_dims,
    position_dim,
)
from ..model.graph_transformer import HeteroGraphTransformer
from ..model.instant_policy_network import InstantPolicyNetwork
from .text_encoder import TextEncoder

LANGUAGE = "language"
LANGUAGE_TO_SCENE = (LANGUAGE, "says", SCENE)
LANGUAGE_TO_GRIPPER = (LANGUAGE, "says", GRIPPER)
CONFIG_FILE, WEIGHTS_FILE = "config.json", "model.safetensors"


class LanguageHeadError(ValueError):
    """Inputs of the wrong shape, a head used with another network or text encoder than its own, a bad save."""


@dataclass
class LanguageHeadConfig:
    """The head's own choices (its sizes that follow the network and encoder are in :class:`HeadBinding`).

    Attributes:
        num_layers: graph transformer layers (the last only updates the gripper nodes).
        num_heads: attention heads per layer (``H`` must be divisible by it).
        mlp_ratio: width of each layer's MLP, in multiples of ``H``.
        temperature: ``τ`` of the contrastive term (:func:`~.training.language_head_loss`).
        regression_weight: weight of the squared error on the bottleneck.
        contrastive_weight: weight of the contrastive term; small by default: on the 12 ``bullet_tabletop`` tasks
            (5 scripted demonstrations each) weights of 0.5 and 2 gave a worse bottleneck error and task ranking on
            held-out episodes than 0.1 or none.
    """

    num_layers: int = 2
    num_heads: int = 4
    mlp_ratio: int = 4
    temperature: float = 0.1
    regression_weight: float = 1.0
    contrastive_weight: float = 0.1

    def __post_init__(self):
        if self.num_layers < 1 or self.num_heads < 1 or self.mlp_ratio < 1:
            raise LanguageHeadError(f"num_layers, num_heads and mlp_ratio must be at least 1, got {self}")
        if not self.temperature > 0:
            raise LanguageHeadError(f"temperature must be positive, got {self.temperature}")
        if min(self.regression_weight, self.contrastive_weight) < 0 or \
                self.regression_weight + self.contrastive_weight == 0:
            raise LanguageHeadError(f"the loss weights must be non-negative and not both zero, got "
                                    f"{self.regression_weight}, {self.contrastive_weight}")


@dataclass
class HeadBinding:
    """What a head was made for: a text encoder (its spec, ``E`` and fingerprint) and a trained network (``H``, the
    gripper keypoints ``(G, 3)`` in the EE frame, the edge encodings' frequencies and a SHA-256 of its weights)."""

    text_encoder: str
    text_dim: int
    text_encoder_fingerprint: str
    hidden_dim: int
    gripper_keypoints: list[list[float]]
    num_frequencies: int
    network_fingerprint: str

    @classmethod
    def of(cls, network: InstantPolicyNetwork, text_encoder: TextEncoder) -> HeadBinding:
        config = network.config
        return cls(text_encoder.spec, text_encoder.dim, text_encoder.fingerprint, config.hidden_dim,
                   [list(map(float, point)) for point in config.gripper_keypoints], config.num_frequencies,
                   network_fingerprint(network))


def network_fingerprint(network: InstantPolicyNetwork) -> str:
    """SHA-256 of the trained network's weights (every tensor of its state dict) and the sizes the head reads."""
    config = network.config
    return encoder_fingerprint(network, {"hidden_dim": config.hidden_dim, "num_frequencies": config.num_frequencies,
                                         "gripper_keypoints": config.gripper_keypoints})


@torch.no_grad()
def current_local_graph(
    network: InstantPolicyNetwork, scene_positions: torch.Tensor, scene_features: torch.Tensor,
    gripper_open: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """What the trained network makes of the current local graph, the head's input: the scene nodes
    ``scene_positions (B, M, 3)`` (current EE frame) with their encoder features ``scene_features (B, M, D)`` and the
    gripper state ``gripper_open (B,)`` (1 open, 0 closed) → the projected scene features ``(B, M, H)`` and σ's
    output at the current gripper nodes ``(B, G, H)`` (what φ receives), without gradients."""
    batch = len(scene_positions)
    network._check_scene_nodes("current", scene_positions, scene_features, (batch,))
    network._check_tensor("gripper_open", gripper_open, (batch,))
    gripper_nodes = network._observation_gripper_features(scene_positions, scene_features, gripper_open,
                                                          leading=(batch,))
    return network.scene_projection(scene_features), gripper_nodes


class LanguageHead(nn.Module):
    """The head (module docstring) for ``binding``'s network and text encoder, with ``config``'s choices."""

    def __init__(self, config: LanguageHeadConfig, binding: HeadBinding):
        super().__init__()
        self.config, self.binding = config, binding
        hidden, frequencies = binding.hidden_dim, binding.num_frequencies
        self.text_projection = nn.Sequential(nn.Linear(binding.text_dim, hidden), nn.GELU(), nn.Linear(hidden, hidden))
        edge_dims = {**local_edge_dims(frequencies), LANGUAGE_TO_SCENE: position_dim(frequencies),
                     LANGUAGE_TO_GRIPPER: position_dim(frequencies)}
        self.graph = HeteroGraphTransformer(edge_dims, [GRIPPER], num_layers=config.num_layers, hidden_dim=hidden,
                                            num_heads=config.num_heads, mlp_ratio=config.mlp_ratio)
        self.register_buffer("gripper_keypoints", torch.tensor(binding.gripper_keypoints, dtype=torch.float32),
                             persistent=False)

    def forward(self, scene_positions: torch.Tensor, scene_nodes: torch.Tensor, gripper_nodes: torch.Tensor,
                text: torch.Tensor) -> torch.Tensor:
        """The predicted bottleneck ``(B, G, H)``.

        Args:
            scene_positions: ``(B, M, 3)`` the scene nodes in the current EE frame.
            scene_nodes: ``(B, M, H)`` their projected features (:func:`current_local_graph`).
            gripper_nodes: ``(B, G, H)`` σ's output at the current gripper nodes (:func:`current_local_graph`).
            text: ``(B, E)`` sentence vectors (:meth:`~.text_encoder.TextEncoder.encode`).
        """
        self._check_inputs(scene_positions, scene_nodes, gripper_nodes, text)
        batch, num_scene = scene_positions.shape[:2]
        frequencies = self.binding.num_frequencies
        keypoints = self.gripper_keypoints.to(scene_positions.dtype).expand(batch, -1, -1)
        origin = scene_positions.new_zeros(batch, 1, 3)
        edge_attr = {
            LANGUAGE_TO_SCENE: dense_position_attr(origin, scene_positions, frequencies),
            LANGUAGE_TO_GRIPPER: dense_position_attr(origin, keypoints, frequencies),
            SCENE_TO_SCENE: dense_position_attr(scene_positions, scene_positions, frequencies),
            SCENE_TO_GRIPPER: dense_position_attr(scene_positions, keypoints, frequencies),
            GRIPPER_TO_GRIPPER: dense_position_attr(keypoints, keypoints, frequencies),
        }
        masks = {**dense_local_masks(num_scene, len(self.gripper_keypoints), scene_positions.device),
                 LANGUAGE_TO_SCENE: None, LANGUAGE_TO_GRIPPER: None}
        nodes = {SCENE: scene_nodes, GRIPPER: gripper_nodes, LANGUAGE: self.text_projection(text)[:, None]}
        return self.graph.forward_dense(nodes, edge_attr, masks)[GRIPPER]

    def bottleneck(self, network: InstantPolicyNetwork, scene_positions: torch.Tensor, scene_features: torch.Tensor,
                   gripper_open: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        """The predicted bottleneck ``(B, G, H)`` from the scene nodes ``(B, M, 3)`` (current EE frame) and encoder
        features ``(B, M, D)``, the gripper state ``(B,)`` and sentence vectors ``(B, E)``, through ``network``'s
        reading of the local graph (:func:`current_local_graph`)."""
        scene_nodes, gripper_nodes = current_local_graph(network, scene_positions, scene_features, gripper_open)
        return self(scene_positions, scene_nodes, gripper_nodes, text)

    def _check_inputs(self, scene_positions, scene_nodes, gripper_nodes, text) -> None:
        batch, hidden = len(scene_positions), self.binding.hidden_dim
        num_scene = scene_positions.shape[1] if scene_positions.ndim == 3 else -1
        expected = {"scene_positions": (scene_positions, (batch, num_scene, 3)),
                    "scene_nodes": (scene_nodes, (batch, num_scene, hidden)),
                    "gripper_nodes": (gripper_nodes, (batch, len(self.gripper_keypoints), hidden)),
                    "text": (text, (batch, self.binding.text_dim))}
        for name, (value, shape) in expected.items():
            if tuple(value.shape) != shape or num_scene < 1:
                raise LanguageHeadError(f"{name} must have shape {shape} (B, M scene nodes, G keypoints, H hidden, "
                                        f"E text), got {tuple(value.shape)}")
            if not torch.isfinite(value).all():
                raise LanguageHeadError(f"{name} contains NaN or infinite values")

    def check_binding(self, network: InstantPolicyNetwork, text_encoder: TextEncoder) -> None:
        """Raise :class:`LanguageHeadError` unless ``network`` and ``text_encoder`` are the ones this head was made
        for (same weights, same encoder)."""
        if network_fingerprint(network) != self.binding.network_fingerprint:
            raise LanguageHeadError("this language head was trained on the bottleneck of another network (its "
                                    "weights differ): train a head for this checkpoint")
        if text_encoder.fingerprint != self.binding.text_encoder_fingerprint:
            raise LanguageHeadError(f"this language head reads sentences encoded by {self.binding.text_encoder!r}, "
                                    f"not by {text_encoder.spec!r} (their fingerprints differ)")

    def save(self, directory: str | Path) -> None:
        """``directory/config.json`` (config and binding) and ``directory/model.safetensors`` (the weights)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        record = {"config": dataclasses.asdict(self.config), "binding": dataclasses.asdict(self.binding)}
        (directory / CONFIG_FILE).write_text(json.dumps(record, indent=2) + "\n")
        save_model(self, str(directory / WEIGHTS_FILE))

    @classmethod
    def load(cls, directory: str | Path, device: str | torch.device = "cpu") -> LanguageHead:
        """The head :meth:`save` wrote to ``directory``, in eval mode on ``device``; every tensor must match."""
        directory = Path(directory)
        for name in (CONFIG_FILE, WEIGHTS_FILE):
            if not (directory / name).is_file():
                raise LanguageHeadError(f"no language head at {directory}: {name} is missing")
        record = json.loads((directory / CONFIG_FILE).read_text())
        try:
            head = cls(config_from_dict(LanguageHeadConfig, record["config"]),
                       config_from_dict(HeadBinding, record["binding"]))
        except (KeyError, TypeError) as error:
            raise LanguageHeadError(f"{directory / CONFIG_FILE} is not a language head's config: {error}") from error
        missing, unexpected = load_model(head, str(directory / WEIGHTS_FILE), strict=False, device=str(device))
        if missing or unexpected:
            raise LanguageHeadError(f"{directory / WEIGHTS_FILE} does not match its config: missing {missing[:5]}, "
                                    f"unexpected {unexpected[:5]}")
        return head.to(device).eval()

