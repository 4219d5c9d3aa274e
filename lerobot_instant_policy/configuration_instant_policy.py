"""``InstantPolicyConfig``: the configuration of Instant Policy (``--policy.type=instant_policy``).

One flag picks the model: ``--policy.preset=small`` (the model that ships, trained on a CPU),
``--policy.preset=paper`` (the paper's model: hidden 1024, 16 heads, ≈124M parameters, its action scene graph with
re-encoded action clouds, 10 encoding frequencies, up to 5 demonstrations per training context) or
``--policy.preset=refined`` (the small model trained to refine the per-object replay of its demonstrations, and run
from it: half of the training rows start from the noised replay prior, inference from the replay noised to a quarter
of the DDIM steps). A field left at ``None`` takes the preset's value; a value given explicitly wins over the
preset. After ``__post_init__`` every field
is set, so a saved ``config.json`` is complete on its own.

This one dataclass configures everything: LeRobot's training loop, the policy, and, handed over as it is, the network
(:class:`~.model.instant_policy_network.InstantPolicyNetwork`), as LeRobot's own policies do. Building it reads no
file: the policy loads the encoder weights (:meth:`~.modeling_instant_policy.InstantPolicyPolicy.load_encoder_weights`).
The ranges of N, L, T, K and S are the network's (:mod:`.model.bounds`), checked here, where the values enter.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from lerobot.configs import NormalizationMode, PolicyFeature, PreTrainedConfig
from lerobot.optim import DiffuserSchedulerConfig

from .contract import POINTCLOUD_KEY
from .geometry.gripper import GRIPPER_KEYPOINTS
from .language.paraphrases import paraphrase_choice
from .model.bounds import (
    MAX_SAMPLES_PER_PREDICTION,
    SUPPORTED_DEMOS,
    SUPPORTED_HORIZON,
    SUPPORTED_INFERENCE_STEPS,
    SUPPORTED_WAYPOINTS,
    check_range,
)
from .model.geometry_encoder import GeometryEncoderConfig, encoder_preset
from .policy.features import (
    check_policy_features,
    contract_input_features,
    contract_output_features,
    identity_normalization,
)
from .replay.plan import replay_plan_name
from .training.optimizer import InstantPolicyAdamWConfig

logger = logging.getLogger(__name__)

PACKAGE_DIR = Path(__file__).resolve().parent
SHIPPED_ENCODER_DIR = PACKAGE_DIR / "assets" / "encoder"
SHIPPED_CHECKPOINT = PACKAGE_DIR / "assets" / "checkpoints" / "instant_policy"  # the pretrained_model these defaults describe
# the same weights run from the per-object replay of the first demonstration (replay_init_strength 0.125, K = 8)
SHIPPED_REPLAY_PRIOR_CHECKPOINT = PACKAGE_DIR / "assets" / "checkpoints" / "instant_policy_replay_prior"

DEFAULT_GRIPPER_KEYPOINTS = GRIPPER_KEYPOINTS

# where a task's context comes from at evaluation: its demonstrations, or its task string through the language head
CONTEXTS = ("demonstrations", "language")

# torch.compile's modes ("reduce-overhead" records CUDA graphs on a GPU).
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")


@dataclass(frozen=True)
class InstantPolicyPreset:
    """The values ``--policy.preset`` fills in: the network's sizes, its graph and the training context."""

    hidden_dim: int
    num_heads: int
    local_layers: int
    context_layers: int
    action_layers: int
    encoder_preset: str
    num_frequencies: int
    action_scene_graph: bool
    reencode_action_clouds: bool
    max_demos: int
    optimizer_lr: float
    refine_fraction: float
    replay_init_strength: float | None
    replay_per_object: bool


_SMALL = dict(hidden_dim=128, num_heads=4, local_layers=2, context_layers=2, action_layers=2, encoder_preset="small",
              num_frequencies=4, action_scene_graph=False, reencode_action_clouds=False, max_demos=2, optimizer_lr=2e-4)
PRESETS: dict[str, InstantPolicyPreset] = {
    "small": InstantPolicyPreset(**_SMALL, refine_fraction=0.0, replay_init_strength=None, replay_per_object=False),
    "paper": InstantPolicyPreset(
        hidden_dim=1024, num_heads=16, local_layers=2, context_layers=2, action_layers=2, encoder_preset="paper",
        num_frequencies=10, action_scene_graph=True, reencode_action_clouds=True, max_demos=5, optimizer_lr=1e-5,
        refine_fraction=0.0, replay_init_strength=None, replay_per_object=False,
    ),
    "refined": InstantPolicyPreset(**_SMALL, refine_fraction=0.5, replay_init_strength=0.25, replay_per_object=True),
}


@PreTrainedConfig.register_subclass("instant_policy")
@dataclass
class InstantPolicyConfig(PreTrainedConfig):
    """Instant Policy (Vosylius & Johns, ICLR 2025): in-context imitation by diffusion over a heterogeneous graph.

    The defaults are the model that ships (``lerobot_instant_policy/assets/checkpoints/instant_policy``, the
    ``small`` preset): with no ``--policy.*`` flag, ``lerobot-train --policy.type=instant_policy`` trains that model
    with its recipe. ``None``: the preset's value (:data:`PRESETS`).

    Inputs: ``observation.pointcloud (P, 3)`` segmented object points in the world frame (m) and
    ``observation.state (8,)`` the EE pose in the world frame (xyz, quaternion xyzw) and ``gripper_open``.
    Output: ``action (8,)`` absolute EE target poses in the same layout; the network predicts ``horizon`` of them.

    Args:
        preset: ``"small"``, ``"paper"`` or ``"refined"``, whose values fill every field left at ``None`` (module
            docstring; default ``"small"``).
        num_demos: N, demonstrations given as context at evaluation, 1…8 (default 2).
        min_demos: the smallest N drawn per training batch, 1…``max_demos`` (default 1).
        max_demos: the largest N drawn per training batch, ``min_demos``…8 (``None``: the preset's, ``paper`` 5,
            ``small`` 2, the N the small model is evaluated with).
        num_waypoints: L, waypoints each demonstration is reduced to, 2…32 (default 10;
            ``data.waypoints.extract_waypoints``).
        horizon: T, future actions predicted per step, 1…32 (default 8); action ``j`` is ``j + 1`` frames ahead.
        inference_steps: K, DDIM denoising steps at inference, 1…8 (default 4).
        diffusion_train_steps: steps of the training noise schedule (squared cosine), at least ``inference_steps``
            (default 100).
        num_scene_nodes: M, scene nodes per local graph; must equal the geometry encoder's number of output centroids
            (default 16, both encoder presets').
        gripper_keypoints: the G gripper nodes' positions in the EE frame (m), one ``(x, y, z)`` each; at least
            three not on one line, since each denoising step fits an SE(3) update to them (default
            :data:`DEFAULT_GRIPPER_KEYPOINTS`, six nodes).
        max_translation: the largest translation (m) of one action step relative to the previous, positive (default
            0.01); with ``max_rotation_deg`` the scale that normalises the flow the network predicts (paper §3.2).
        max_rotation_deg: the largest rotation (degrees) of one action step, positive (default 3.0).
        hidden_dim: H, node features, at least 1 and divisible by ``num_heads`` (``None``: the preset's, ``small``
            128, ``paper`` 1024).
        num_heads: attention heads of every graph-transformer layer, at least 1 (``None``: ``small`` 4, ``paper`` 16).
        local_layers: graph-transformer layers of σ, on the local graphs, at least 1 (``None``: the preset's, 2).
        context_layers: layers of φ, demonstrations → current, at least 1 (``None``: the preset's, 2).
        action_layers: layers of ψ, current → actions, at least 1 (``None``: the preset's, 2).
        mlp_ratio: the width of each layer's feed-forward block over ``hidden_dim``, at least 1 (default 4).
        num_frequencies: D, sinusoidal frequencies 2⁰π…2^(D−1)π of the edge and timestep encodings, at least 1
            (``None``: ``small`` 4, ``paper`` 10, the paper's).
        encoder_preset: the frozen geometry encoder's architecture, ``"small"`` or ``"paper"`` (``None``: the
            preset's).
        encoder_weights: its weights, a ``.safetensors`` written by ``lerobot-ip-pretrain-encoder`` with its
            ``.json`` beside it (default ``None``:
            ``lerobot_instant_policy/assets/encoder/<encoder_preset>.safetensors``). Read only when a policy is built
            from scratch: a checkpoint carries its encoder.
        pretrained_encoder: ``False`` keeps the frozen encoder randomly initialised, for an architecture without
            pretrained weights, such as ``paper``'s before ``lerobot-ip-pretrain-encoder`` has trained them (default
            ``True``).
        action_scene_graph: the action gripper nodes run σ on the scene seen from their noisy poses (the paper's
            graph); ``False`` lets them see the scene only through the current nodes, so every path from the scene
            to an action passes φ (``None``: ``small`` false, ``paper`` true).
        reencode_action_clouds: with ``action_scene_graph``, re-encode the live cloud in every action frame at every
            denoising step (the paper's) instead of moving the encoded scene nodes rigidly into the action frames
            (``None``: ``small`` false, ``paper`` true).
        cache_frame_encodings: compute the frozen encoder's output for every frame of the training dataset once and
            store it beside the dataset (``frame_encodings``; rebuilt when the encoder or the dataset changes), so
            training steps read scene nodes instead of encoding clouds (default ``True``).
        compile_model: run σ, φ and ψ's layers through ``torch.compile`` in the training step, sampling eager; it
            compiles again for every new input shape (default ``False``).
        compile_inference: the same layers compiled for sampling; it compiles again for every new N or batch size
            (default ``False``).
        compile_mode: ``torch.compile``'s mode, one of :data:`COMPILE_MODES` (default ``"default"``).
        gripper_flip_probability: of the current gripper state being flipped per training sample (the input only,
            never the label), in [0, 1] (default 0.1).
        gripper_loss_weight: the weight of the gripper's binary cross-entropy in the loss, next to the translation
            and rotation flow errors, non-negative (default 0.01).
        optimizer_lr: AdamW's peak learning rate, positive (``None``: ``small`` 2e-4, the rate of the shipped
            checkpoint's training on the pseudo-task stream, ``paper`` 1e-5). AdamW runs PyTorch's fused kernel on
            the CPU and CUDA (:class:`~.training.optimizer.InstantPolicyAdamWConfig`).
        optimizer_betas: AdamW's betas (default (0.9, 0.999)).
        optimizer_eps: AdamW's eps (default 1e-8).
        optimizer_weight_decay: AdamW's weight decay (default 0.01).
        optimizer_grad_clip_norm: gradients are clipped to this norm, positive (default 1.0).
        scheduler_warmup_steps: linear warmup steps, then cosine decay to zero, non-negative (default 100).
        demo_repo_id: the LeRobotDataset whose episodes of the env's task are the context at evaluation (read
            offline from ``demo_root``; default ``None``: none, demonstrations are handed in with
            ``set_demonstrations``). A batch without ``task`` uses its task when it holds one.
        demo_root: its local directory (default ``None``: LeRobot's cache, ``$HF_LEROBOT_HOME/<demo_repo_id>``).
        context: where a task's context comes from at evaluation, one of :data:`CONTEXTS` (default
            ``"demonstrations"``: its demonstrations). ``"language"``: the task said in words, the batch's ``task``
            string through a language head (:mod:`.language.task_language`, docs/language.md), for every task whose
            demonstrations were not handed in with ``set_demonstrations``; no ``demo_repo_id``, no replay start.
        language_head_path: the language head's directory (``lerobot-ip-train-language``'s ``OUT/head``), made for
            this checkpoint's weights (default ``None``: the head shipped for the shipped checkpoint,
            ``lerobot_instant_policy/assets/language/head``).
        language_paraphrase: with ``context="language"``, the sentence that says a task string of the paraphrase
            file (``push_button``, ``reach-v3``): ``SPLIT:K``, the K-th of its ``seen`` or ``held_out`` sentences
            (default ``"seen:0"``); any other task string is read as the sentence itself.
        language_instruction: with ``context="language"``, what every row is told instead of its own ``task``
            string: a task name of the paraphrase file (said with ``language_paraphrase``) or a sentence (default
            ``None``: each row's task). An instruction of the user's own where the env's task string is not what
            they mean to say; the suite's context-swap control tells each task another task's name.
        n_action_steps: actions of each prediction run before predicting again, 1…``horizon`` (default 8).
        replan_on_gripper_change: drop the queued actions after one that changes the gripper command, so the policy
            looks again once the gripper has acted (default ``True``).
        replay_init_strength: s in (0, 1] starts denoising from the demonstrated actions replayed into the live scene
            (yaw-only ICP of the demonstrations' first clouds onto the live one, :func:`~.replay.plan.
            plan_replay`) noised to the last ⌈s·K⌉ DDIM steps, instead of from pure noise (``None``: the preset's;
            ``small`` and ``paper``: pure noise, the paper's; ``refined``: 0.25).
        replay_per_object: plan that replay per object (the grasp follows the grasped object, the release the other
            one) where two objects move independently; in training to refine, the priors too (``None``: the
            preset's, ``True`` for ``refined``, else ``False``).
        replay_anchored: plan that replay per segment instead, each segment following the object it approaches
            (:mod:`~.replay.segments`); excludes ``replay_per_object`` (default ``False``).
        replay_consensus: plan it anchored, per object and whole, and start from the plan whose demonstrations agree
            best in the live scene (:func:`~.replay.plan.plan_each`); excludes the two above (default ``False``).
        replay_trust_m: with ``replay_init_strength``, the distrust range ``(start, end)`` in metres over which an
            episode's start strength rises from ``replay_init_strength`` to the paper's start from noise, by how
            poorly the replay's registration fits and how far the demonstrations' own plans part in the live scene
            (:mod:`~.replay.trust`); ``None`` (default): ``replay_init_strength`` in every episode.
        refine_fraction: the share of training rows whose noised sample starts from the row's replay prior
            (``observation.replay_prior``, :mod:`.replay.priors`, which the pseudo-task stream and pool
            supply when this is positive) instead of its clean actions, the target staying the clean actions: the
            network learns to correct the replay it starts from at inference. Every other row keeps the paper's
            loss on the same weights (``None``: the preset's; 0 for ``small`` and ``paper``, 0.5 for ``refined``).
        refine_max_strength: a refined row's noise timestep is drawn uniformly from the first
            ``⌈refine_max_strength · diffusion_train_steps⌉``, where inference with ``replay_init_strength`` up to
            this value starts, in (0, 1] (default 0.5).
        samples_per_prediction: S, each prediction is the mean of S samples from S noise draws, 1…64 (default 1, the
            paper's); the action passes run on S rows instead of one.
        use_amp: (LeRobot's) autocast in training and evaluation, bfloat16 on the CPU and float16 on CUDA (default
            ``False``); ``__post_init__`` turns it off on a CPU without fast bfloat16 kernels, where it slows
            training down.

    What each default and option measured is in docs/policy.md.
    """

    preset: str = "small"

    num_demos: int = 2
    min_demos: int = 1
    max_demos: int | None = None
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
    num_frequencies: int | None = None

    encoder_preset: str | None = None
    encoder_weights: str | None = None
    pretrained_encoder: bool = True
    action_scene_graph: bool | None = None
    reencode_action_clouds: bool | None = None
    cache_frame_encodings: bool = True
    compile_model: bool = False
    compile_inference: bool = False
    compile_mode: str = "default"

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
    context: str = "demonstrations"
    language_head_path: str | None = None
    language_paraphrase: str = "seen:0"
    language_instruction: str | None = None

    n_action_steps: int = 8
    replan_on_gripper_change: bool = True
    replay_init_strength: float | None = None
    replay_per_object: bool | None = None
    replay_anchored: bool = False
    replay_consensus: bool = False
    replay_trust_m: tuple[float, float] | None = None
    refine_fraction: float | None = None
    refine_max_strength: float = 0.5
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
        for preset_field in fields(preset):
            if getattr(self, preset_field.name) is None:
                setattr(self, preset_field.name, getattr(preset, preset_field.name))
        self.gripper_keypoints = [[float(value) for value in point] for point in self.gripper_keypoints]
        if self.use_amp and self.device == "cpu" and not cpu_has_fast_bfloat16():
            # as LeRobot's PreTrainedConfig deactivates AMP where a device has none
            logger.warning(
                "use_amp deactivated: this CPU (%s) has no fast bfloat16 kernels, where autocast slows training down "
                "(docs/benchmarks.md)",
                torch.backends.cpu.get_cpu_capability(),
            )
            self.use_amp = False
        self._validate()

    def _validate(self) -> None:
        check_range("num_demos (N)", self.num_demos, SUPPORTED_DEMOS)
        check_range("min_demos", self.min_demos, SUPPORTED_DEMOS)
        check_range("max_demos", self.max_demos, SUPPORTED_DEMOS)
        if self.min_demos > self.max_demos:
            raise ValueError(f"min_demos ({self.min_demos}) must not exceed max_demos ({self.max_demos})")
        check_range("num_waypoints (L)", self.num_waypoints, SUPPORTED_WAYPOINTS)
        check_range("horizon (T)", self.horizon, SUPPORTED_HORIZON)
        check_range("inference_steps (K)", self.inference_steps, SUPPORTED_INFERENCE_STEPS)
        check_range("samples_per_prediction (S)", self.samples_per_prediction, (1, MAX_SAMPLES_PER_PREDICTION))
        if self.diffusion_train_steps < self.inference_steps:
            raise ValueError(
                f"diffusion_train_steps ({self.diffusion_train_steps}) must be at least inference_steps "
                f"({self.inference_steps})"
            )
        if self.replay_init_strength is not None and not 0.0 < self.replay_init_strength <= 1.0:
            raise ValueError(f"replay_init_strength must lie in (0, 1] or be None, got {self.replay_init_strength}")
        if self.replay_trust_m is not None:
            if not self.replay_init_strength:
                raise ValueError("replay_trust_m sets how far an episode's start strength rises from "
                                 "replay_init_strength: set replay_init_strength to use it")
            if len(self.replay_trust_m) != 2 or not 0.0 <= self.replay_trust_m[0] < self.replay_trust_m[1]:
                raise ValueError(f"replay_trust_m must be (start, end) metres with 0 ≤ start < end, got "
                                 f"{self.replay_trust_m}")
            self.replay_trust_m = (float(self.replay_trust_m[0]), float(self.replay_trust_m[1]))
        if not 0.0 <= self.refine_fraction <= 1.0:
            raise ValueError(f"refine_fraction must lie in [0, 1], got {self.refine_fraction}")
        self.replay_plan()
        if not 0.0 < self.refine_max_strength <= 1.0:
            raise ValueError(f"refine_max_strength must lie in (0, 1], got {self.refine_max_strength}")
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
        self._validate_context()
        if self.compile_mode not in COMPILE_MODES:
            raise ValueError(f"compile_mode must be one of {list(COMPILE_MODES)}, got {self.compile_mode!r}")
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

    def _validate_context(self) -> None:
        if self.context not in CONTEXTS:
            raise ValueError(f"context must be one of {list(CONTEXTS)}, got {self.context!r}")
        try:
            paraphrase_choice(self.language_paraphrase)
        except ValueError as error:
            raise ValueError(f"language_paraphrase: {error}") from error
        if self.context != "language":
            if self.language_instruction is not None:
                raise ValueError(f"language_instruction {self.language_instruction!r} is said in words only with "
                                 "context='language'")
            return
        if self.language_instruction is not None and not self.language_instruction.strip():
            raise ValueError("language_instruction must be a non-blank task name or sentence, or None (each row's "
                             "task)")
        if self.demo_repo_id is not None:
            raise ValueError(f"context='language' says each task in words, without demonstrations, but demo_repo_id is "
                             f"{self.demo_repo_id!r}: drop demo_repo_id, or use context='demonstrations'")
        if self.replay_init_strength:
            raise ValueError("context='language' has no demonstrations to replay: set replay_init_strength to None "
                             "(the refined preset sets 0.25), or use context='demonstrations'")

    def _validate_encoder(self) -> None:
        if self.encoder_config.num_nodes != self.num_scene_nodes:
            raise ValueError(
                f"num_scene_nodes (M={self.num_scene_nodes}) must equal the {self.encoder_preset!r} geometry encoder's "
                f"{self.encoder_config.num_nodes} output centroids"
            )
        if self.encoder_weights is not None and not self.encoder_weights.endswith(".safetensors"):
            raise ValueError(f"encoder_weights must name a .safetensors file, got {self.encoder_weights!r}")

    def replay_plan(self) -> str:
        """The replay plan ``replay_per_object``, ``replay_anchored`` and ``replay_consensus`` name
        (:data:`~.replay.plan.REPLAY_PLANS`)."""
        return replay_plan_name(self.replay_per_object, self.replay_anchored, self.replay_consensus)

    @property
    def encoder_config(self) -> GeometryEncoderConfig:
        """The frozen geometry encoder's architecture, ``encoder_preset``'s."""
        return encoder_preset(self.encoder_preset)

    def encoder_weights_path(self) -> Path:
        """The encoder weights file: ``encoder_weights``, or the shipped weights of ``encoder_preset``."""
        if self.encoder_weights is not None:
            return Path(self.encoder_weights).expanduser()
        return SHIPPED_ENCODER_DIR / f"{self.encoder_preset}.safetensors"

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

