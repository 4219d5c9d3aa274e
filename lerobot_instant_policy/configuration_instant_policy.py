"""``InstantPolicyConfig``: the configuration of Instant Policy (``--policy.type=instant_policy``).

One flag picks the network sizes: ``--policy.preset=small`` (CPU) or ``--policy.preset=paper`` (hidden 1024, 16 heads,
≈118M parameters, the paper's model). A size field left at ``None`` takes the preset's value; a size given explicitly
wins over the preset. After ``__post_init__`` every size is set, so a saved ``config.json`` is complete on its own.

This one dataclass configures everything: LeRobot's training loop, the policy, and, handed over as it is, the network
(:class:`~.model.instant_policy_network.InstantPolicyNetwork`), as LeRobot's own policies do. Building it reads no
file: the encoder weights are loaded in an explicit step of the policy
(:meth:`~.modeling_instant_policy.InstantPolicyPolicy.load_encoder_weights`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from lerobot.configs import NormalizationMode, PolicyFeature, PreTrainedConfig
from lerobot.optim import DiffuserSchedulerConfig

from .contract import POINTCLOUD_KEY
from .geometry.gripper import GRIPPER_KEYPOINTS
from .model.action_diffusion import LOSS_WEIGHTINGS
from .model.geometry_encoder import GeometryEncoderConfig, encoder_preset
from .model.instant_policy_network import SUPPORTED_DEMOS, SUPPORTED_WAYPOINTS
from .policy.features import (
    check_policy_features,
    contract_input_features,
    contract_output_features,
    identity_normalization,
)
from .policy.optimizer import InstantPolicyAdamWConfig

PACKAGE_DIR = Path(__file__).resolve().parent
SHIPPED_ENCODER_DIR = PACKAGE_DIR / "assets" / "encoder"
SHIPPED_CHECKPOINT = PACKAGE_DIR / "assets" / "checkpoints" / "instant_policy"  # the pretrained_model these defaults describe

# T and K the network is built for (N and L: the network's SUPPORTED_DEMOS, SUPPORTED_WAYPOINTS).
SUPPORTED_HORIZON = (1, 32)
SUPPORTED_INFERENCE_STEPS = (1, 8)
MAX_SAMPLES_PER_PREDICTION = 64  # samples_per_prediction: a batch of S × rows per prediction

DEFAULT_GRIPPER_KEYPOINTS = GRIPPER_KEYPOINTS

# torch.compile's modes ("reduce-overhead" records CUDA graphs on a GPU).
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")


@dataclass(frozen=True)
class InstantPolicyPreset:
    """Sizes and learning rate that ``--policy.preset`` fills in."""

    hidden_dim: int
    num_heads: int
    local_layers: int
    context_layers: int
    action_layers: int
    encoder_preset: str
    optimizer_lr: float


PRESETS: dict[str, InstantPolicyPreset] = {
    "small": InstantPolicyPreset(
        hidden_dim=128, num_heads=4, local_layers=2, context_layers=2, action_layers=2, encoder_preset="small",
        optimizer_lr=1e-3,
    ),
    "paper": InstantPolicyPreset(
        hidden_dim=1024, num_heads=16, local_layers=2, context_layers=2, action_layers=2, encoder_preset="paper",
        optimizer_lr=1e-5,
    ),
}


@PreTrainedConfig.register_subclass("instant_policy")
@dataclass
class InstantPolicyConfig(PreTrainedConfig):
    """Instant Policy (Vosylius & Johns, ICLR 2025): in-context imitation by diffusion over a heterogeneous graph.

    The defaults are the model that ships (``lerobot_instant_policy/assets/checkpoints/instant_policy``): with no
    ``--policy.*`` flag, ``lerobot-train --policy.type=instant_policy`` trains that model with its recipe. Where the
    shipped model departs from the paper, the field says so and names the paper's value; old checkpoints keep the
    values saved in their ``config.json``.

    Inputs: ``observation.pointcloud (P, 3)`` segmented object points in the world frame (m) and
    ``observation.state (8,)`` the EE pose in the world frame (xyz, quaternion xyzw) and ``gripper_open``.
    Output: ``action (8,)`` absolute EE target poses in the same layout; the network predicts ``horizon`` of them.

    Context and prediction:
        num_demos: N, demonstrations given as context at evaluation.
        min_demos, max_demos: range from which N is drawn per training batch (the paper: 1…5; shipped: 1…2, the
            N it is evaluated with, which learned the context faster on CPU budgets).
        num_waypoints: L, waypoints each demonstration is reduced to (``data.waypoints.extract_waypoints``).
        horizon: T, future actions predicted per step; action ``j`` is ``j + 1`` frames ahead.
        inference_steps: K, DDIM denoising steps at inference.
        diffusion_train_steps: steps of the training noise schedule (squared cosine).
        num_scene_nodes: M, scene nodes per local graph; the geometry encoder's number of output centroids.
        gripper_keypoints: the G gripper nodes' positions in the EE frame (m), one ``(x, y, z)`` each; at least
            three not on one line, since each denoising step fits an SE(3) update to them.
        max_translation, max_rotation_deg: the largest translation (m) and rotation (degrees) of one action step
            relative to the previous, the scale that normalises the flow the network predicts (paper §3.2).

    Network (``None``: the preset's value): hidden_dim, num_heads (``hidden_dim`` must divide by it), and the
    number of graph-transformer layers of σ (``local_layers``, the local graphs), φ (``context_layers``,
    demonstrations → current) and ψ (``action_layers``, current → actions); ``mlp_ratio``, the width of each
    layer's feed-forward block over ``hidden_dim``; ``num_frequencies``, the sinusoidal frequencies of the edge
    and timestep encodings (the paper: 10; shipped: 4, the best held-out context gain measured on CPU).

    Geometry encoder (frozen): ``encoder_preset`` (``None``: the preset's) names its architecture; its weights come
    from ``encoder_weights`` (a ``.safetensors`` written by ``lerobot-ip-pretrain-encoder`` with its ``.json``
    beside it; ``None``: the weights shipped in ``lerobot_instant_policy/assets/encoder/<encoder_preset>.safetensors``).
    ``pretrained_encoder=False`` uses a randomly initialised frozen encoder instead (tests, benchmarks).
    Weights whose recorded architecture differs from ``encoder_preset`` are refused. A checkpoint carries the
    encoder in its ``model.safetensors``, so the weights file is only read when a policy is built from scratch.

    The graph (the paper's graph: ``action_scene_graph=true reencode_action_clouds=true num_frequencies=10``):
    ``action_scene_graph``: the action gripper nodes run σ on the scene seen from their noisy poses (the paper's
    graph); ``False`` (shipped) lets them see the scene only through the current nodes, so every path from the scene
    to an action passes the demonstrations' φ (issue 11: a higher held-out context gain in one object layout).
    ``reencode_action_clouds`` (only with ``action_scene_graph``): re-encode the live cloud in every action frame at
    every denoising step (the paper's choice) rather than moving the encoded scene nodes rigidly into the action
    frames. ``context_scene_edges``: φ's current gripper nodes also attend to the live scene nodes (edges scene →
    current, ``enc(k − p)`` in the current EE frame), so that which part of the scene they read can depend on the
    demonstrations; in the paper's graph (``False``) the scene is read only by σ, before any demonstration is seen.
    ``dense_attention``: run the graph-transformer layers of σ, φ and ψ in a dense batched layout (the same weights
    and outputs as the torch-geometric ``TransformerConv`` layers, which ``False`` runs instead).

    Training: with ``cache_frame_encodings`` the frozen encoder's output for every frame of the training dataset is
    computed once and stored beside the dataset (``frame_encodings``; rebuilt when the encoder or the dataset
    changes), so training steps read scene nodes instead of encoding clouds. With ``compile_model`` (as LeRobot's
    own policies name it; it needs ``dense_attention``) the dense layers of σ, φ and ψ run through ``torch.compile``
    with ``compile_mode`` (one of :data:`COMPILE_MODES`) in the training step, while sampling stays eager
    (``lerobot-ip-bench train-step --compare-compile-model`` measures its ratio on the machine at hand), after about
    100 s of compiling per new shape. With ``compile_inference`` the same layers are compiled for sampling too (a
    control step under ``inference_mode``; set it when loading a checkpoint, ``--policy.compile_inference=true``): see
    ``lerobot-ip-bench inference --compare-compile-inference`` for its ratio and the seconds the first control step
    spends compiling (again for each new number of demonstrations or batch size). LeRobot's ``use_amp`` trains in
    bfloat16 autocast on the CPU: faster on CPUs with AMX, slower without (0.74× float32 measured on AVX-512 bf16
    without AMX), so it stays off unless ``--compare-amp`` measures a gain. ``gripper_flip_probability`` of the
    current gripper state (the input only, never the label) being flipped per sample; the loss is the translation and
    rotation flow errors (weighted over diffusion timesteps by ``flow_loss_weighting``: ``uniform``, the paper's, or
    ``noise``, by the noise variance) plus ``gripper_loss_weight`` times the gripper's binary cross-entropy (shipped:
    0.01; on rung 2 of the pseudo-task ladder 0.1 kept the network from reading its demonstrations and 0.01 did not;
    docs/results.md), averaged over ``noise_draws`` diffusion timesteps and noises per sample (σ and φ, which do not
    depend on the noisy actions, run once per sample: a lower-variance estimate of the same loss for the cost of ψ);
    N is drawn per batch and capped at the fewest other episodes a row's task has (a demonstration never repeats in
    one context); AdamW (PyTorch's fused kernel on the CPU and CUDA, :class:`~.optimizer.InstantPolicyAdamWConfig`)
    with ``optimizer_lr`` (``None``: the preset's, 1e-5 for ``paper`` as in the paper, 1e-3 for ``small``, the
    shipped model's), linear warmup over ``scheduler_warmup_steps`` then cosine decay to zero, gradients clipped to
    ``optimizer_grad_clip_norm``.

    Evaluation: the episodes of the env's task in the LeRobotDataset ``demo_repo_id`` at ``demo_root`` (read
    offline) are the context. Execution: ``n_action_steps`` (≤ ``horizon``) actions of each prediction are run
    before predicting again, and with ``replan_on_gripper_change`` the queue is dropped after an action that
    changes the gripper command, so the policy looks again once the gripper has acted.

    Beyond the paper (issue 30.4): with ``replay_init_strength`` = s in (0, 1] denoising starts from the
    demonstrated actions replayed into the live scene instead of from pure noise. At an episode's first prediction
    the demonstrations' first-frame clouds are registered onto the live cloud (the ``demo_replay`` baseline's
    :func:`~.data.replay_plan.plan_replay`, yaw-only trimmed ICP) and the best fit's actions, moved by the estimated
    motion, become the plan; each prediction takes the plan's next ``horizon`` actions from the episode's step count,
    noises them to the timestep of the last ⌈s·K⌉ of the K DDIM steps and runs only those (SDEdit). ``None`` (shipped):
    the paper's path, pure noise, the demonstrations read through the graph alone. ``replay_per_object``: plan the
    replay per object (the grasp follows the grasped object, the release the other one) where two objects move
    independently, as ``demo_replay``'s ``registration_per_object``. ``samples_per_prediction`` = S > 1: each
    prediction is the mean of S samples from S noise draws (per action the mean translation, the chordal mean rotation
    and the sign of the mean gripper variable; :meth:`~.model.instant_policy_network.InstantPolicyNetwork.
    sample_actions`); 1 (shipped): the paper's single sample.
    """

    preset: str = "small"

    num_demos: int = 2
    min_demos: int = 1
    max_demos: int = 2
    num_waypoints: int = 10
    horizon: int = 8
    inference_steps: int = 4
    diffusion_train_steps: int = 100
    num_scene_nodes: int = 16
    gripper_keypoints: list[list[float]] = field(default_factory=lambda: [list(p) for p in DEFAULT_GRIPPER_KEYPOINTS])
    max_translation: float = 0.01
    max_rotation_deg: float = 3.0

    hidden_dim: int | None = None
    num_heads: int | None = None
    local_layers: int | None = None
    context_layers: int | None = None
    action_layers: int | None = None
    mlp_ratio: int = 4
    num_frequencies: int = 4

    encoder_preset: str | None = None
    encoder_weights: str | None = None
    pretrained_encoder: bool = True
    reencode_action_clouds: bool = False
    dense_attention: bool = True
    action_scene_graph: bool = False
    context_scene_edges: bool = False
    cache_frame_encodings: bool = True
    compile_model: bool = False
    compile_inference: bool = False
    compile_mode: str = "default"
    flow_loss_weighting: str = "uniform"
    noise_draws: int = 1

    gripper_flip_probability: float = 0.1
    gripper_loss_weight: float = 0.01
    optimizer_lr: float | None = None
    optimizer_betas: tuple[float, float] = (0.9, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-2
    optimizer_grad_clip_norm: float = 1.0
    scheduler_warmup_steps: int = 100

    demo_repo_id: str | None = None
    demo_root: str | None = None

    n_action_steps: int = 8
    replan_on_gripper_change: bool = True
    replay_init_strength: float | None = None
    replay_per_object: bool = False
    samples_per_prediction: int = 1

    push_to_hub: bool = False

    input_features: dict[str, PolicyFeature] | None = field(default_factory=contract_input_features)
    output_features: dict[str, PolicyFeature] | None = field(default_factory=contract_output_features)
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}; known presets: {sorted(PRESETS)}")
        preset = PRESETS[self.preset]
        for name in ("hidden_dim", "num_heads", "local_layers", "context_layers", "action_layers",
                     "encoder_preset", "optimizer_lr"):
            if getattr(self, name) is None:
                setattr(self, name, getattr(preset, name))
        self.gripper_keypoints = [[float(value) for value in point] for point in self.gripper_keypoints]
        if self.use_amp and self.device == "cpu" and not cpu_has_fast_bfloat16():
            # as LeRobot's PreTrainedConfig deactivates AMP where a device has none
            logging.getLogger(__name__).warning(
                "use_amp deactivated: this CPU (%s) has no fast bfloat16 kernels, where autocast measured 0.1x the "
                "float32 training speed (lerobot-ip-bench train-step --compare-amp)",
                torch.backends.cpu.get_cpu_capability(),
            )
            self.use_amp = False
        self._validate()

    def _validate(self) -> None:
        _check_range("num_demos (N)", self.num_demos, SUPPORTED_DEMOS)
        _check_range("min_demos", self.min_demos, SUPPORTED_DEMOS)
        _check_range("max_demos", self.max_demos, SUPPORTED_DEMOS)
        if self.min_demos > self.max_demos:
            raise ValueError(f"min_demos ({self.min_demos}) must not exceed max_demos ({self.max_demos})")
        _check_range("num_waypoints (L)", self.num_waypoints, SUPPORTED_WAYPOINTS)
        _check_range("horizon (T)", self.horizon, SUPPORTED_HORIZON)
        _check_range("inference_steps (K)", self.inference_steps, SUPPORTED_INFERENCE_STEPS)
        if self.diffusion_train_steps < self.inference_steps:
            raise ValueError(
                f"diffusion_train_steps ({self.diffusion_train_steps}) must be at least inference_steps "
                f"({self.inference_steps})"
            )
        if not 1 <= self.samples_per_prediction <= MAX_SAMPLES_PER_PREDICTION:
            raise ValueError(f"samples_per_prediction must be in 1…{MAX_SAMPLES_PER_PREDICTION}, got "
                             f"{self.samples_per_prediction}")
        if self.replay_init_strength is not None and not 0.0 < self.replay_init_strength <= 1.0:
            raise ValueError(f"replay_init_strength must lie in (0, 1] or be None, got {self.replay_init_strength}")
        if not 1 <= self.n_action_steps <= self.horizon:
            raise ValueError(f"n_action_steps must lie in 1…horizon ({self.horizon}), got {self.n_action_steps}")
        if self.n_obs_steps != 1:
            raise ValueError(
                f"instant_policy reads the current observation only: n_obs_steps must be 1, got {self.n_obs_steps}"
            )
        for name in ("hidden_dim", "num_heads", "local_layers", "context_layers", "action_layers", "mlp_ratio",
                     "num_frequencies"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.hidden_dim % self.num_heads:
            raise ValueError(f"hidden_dim ({self.hidden_dim}) must be divisible by num_heads ({self.num_heads})")
        keypoints = np.asarray(self.gripper_keypoints, dtype=float)
        if keypoints.ndim != 2 or keypoints.shape[1] != 3 or not np.isfinite(keypoints).all():
            raise ValueError(
                f"gripper_keypoints must be a list of finite (x, y, z) points, got {self.gripper_keypoints}"
            )
        if np.linalg.matrix_rank(keypoints - keypoints.mean(axis=0), tol=1e-6) < 2:
            raise ValueError(
                "gripper_keypoints need at least 3 points not on one line (an SE(3) update is fitted to them), got "
                f"{self.gripper_keypoints}"
            )
        if self.max_translation <= 0 or self.max_rotation_deg <= 0:
            raise ValueError(
                f"max_translation and max_rotation_deg must be positive, got {self.max_translation}, "
                f"{self.max_rotation_deg}"
            )
        if self.flow_loss_weighting not in LOSS_WEIGHTINGS:
            raise ValueError(
                f"flow_loss_weighting must be one of {list(LOSS_WEIGHTINGS)}, got {self.flow_loss_weighting!r}"
            )
        if self.compile_mode not in COMPILE_MODES:
            raise ValueError(f"compile_mode must be one of {list(COMPILE_MODES)}, got {self.compile_mode!r}")
        if (self.compile_model or self.compile_inference) and not self.dense_attention:
            raise ValueError("compile_model and compile_inference compile the dense layers: they need "
                             "dense_attention=true")
        if not isinstance(self.noise_draws, int) or self.noise_draws < 1:
            raise ValueError(f"noise_draws must be a positive integer, got {self.noise_draws!r}")
        if self.gripper_loss_weight < 0:
            raise ValueError(f"gripper_loss_weight must be non-negative, got {self.gripper_loss_weight}")
        if not 0.0 <= self.gripper_flip_probability <= 1.0:
            raise ValueError(f"gripper_flip_probability must lie in [0, 1], got {self.gripper_flip_probability}")
        if self.optimizer_lr <= 0 or self.optimizer_grad_clip_norm <= 0 or self.scheduler_warmup_steps < 0:
            raise ValueError(
                "optimizer_lr and optimizer_grad_clip_norm must be positive and scheduler_warmup_steps "
                f"non-negative, got {self.optimizer_lr}, {self.optimizer_grad_clip_norm}, {self.scheduler_warmup_steps}"
            )
        self._validate_encoder()

    def _validate_encoder(self) -> None:
        if self.encoder_config.num_nodes != self.num_scene_nodes:
            raise ValueError(
                f"num_scene_nodes (M={self.num_scene_nodes}) must equal the {self.encoder_preset!r} geometry encoder's "
                f"{self.encoder_config.num_nodes} output centroids"
            )
        if self.encoder_weights is not None and not self.encoder_weights.endswith(".safetensors"):
            raise ValueError(f"encoder_weights must name a .safetensors file, got {self.encoder_weights!r}")

    @property
    def encoder_config(self) -> GeometryEncoderConfig:
        """The frozen geometry encoder's architecture, ``encoder_preset``'s."""
        return encoder_preset(self.encoder_preset)

    def encoder_weights_path(self) -> Path:
        """The encoder weights file: ``encoder_weights``, or the shipped weights of ``encoder_preset``."""
        if self.encoder_weights is not None:
            return Path(self.encoder_weights).expanduser()
        return SHIPPED_ENCODER_DIR / f"{self.encoder_preset}.safetensors"

    def require_encoder_weights(self) -> Path:
        """``encoder_weights_path()`` if it exists; a ``FileNotFoundError`` that says how to get weights if not."""
        path = self.encoder_weights_path()
        if not path.is_file():
            raise FileNotFoundError(
                f"no geometry encoder weights at {path}: train them with `lerobot-ip-pretrain-encoder --preset "
                f"{self.encoder_preset} --out FILE.safetensors` and pass --policy.encoder_weights=FILE.safetensors, "
                "or set --policy.pretrained_encoder=false for a randomly initialised frozen encoder"
            )
        return path

    def validate_features(self) -> None:
        """The policy reads ``observation.pointcloud (P, 3)`` and ``observation.state (8,)``, writes ``action (8,)``."""
        check_policy_features("instant_policy", self.input_features, self.output_features)
        if self.num_points < self.encoder_config.num_centroids[0]:
            raise ValueError(
                f"clouds of {self.num_points} points are fewer than the {self.encoder_preset!r} geometry encoder's "
                f"{self.encoder_config.num_centroids[0]} first-level centroids"
            )

    @property
    def num_points(self) -> int:
        """P, the points per cloud the policy expects (from ``input_features``)."""
        return int(self.input_features[POINTCLOUD_KEY].shape[0])

    def get_optimizer_preset(self) -> InstantPolicyAdamWConfig:
        return InstantPolicyAdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name="cosine", num_warmup_steps=self.scheduler_warmup_steps)

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        """None: LeRobot delivers each training row's own action only. The policy reads the row's ``horizon``-step
        chunk (targets ``1 … horizon`` frames ahead) from the dataset's action table itself (``ActionChunks``),
        because LeRobot's delta-timestamp query formats the queried rows' point clouds too (30 ms per row here)."""
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None


def cpu_has_fast_bfloat16() -> bool:
    """Whether oneDNN has bfloat16 kernels for this CPU (AVX-512 or newer); on an AVX2 CPU bfloat16 matrix products
    are emulated and autocast slows training down instead of speeding it up."""
    return bool(torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported())


def _check_range(name: str, value: int, bounds: tuple[int, int]) -> None:
    low, high = bounds
    if not isinstance(value, int) or not low <= value <= high:
        raise ValueError(f"{name} must be an integer in the supported range {low}…{high}, got {value!r}")
