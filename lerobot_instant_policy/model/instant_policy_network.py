"""The Instant Policy network: frozen geometry encoder, graph, σ / φ / ψ and the action diffusion (paper §3).

Frames: ``W`` is a world frame (each demonstration and the live scene may have their own); ``E`` is the end-effector
frame of a time step; ``A`` an action frame. Inputs to the network:

- demonstrations (:class:`DemoTensors`): ``T_world_ee (B, N, L, 4, 4)``, ``gripper_open (B, N, L)`` (1 open,
  0 closed) and the frozen encoder's scene nodes of each waypoint's cloud in its own EE frame;
- the current observation: ``points_world (B, P, 3)``, ``T_world_ee (B, 4, 4)``, ``gripper (B,)`` (1 open, 0 closed);
- training targets: ``T_ee_actions (B, T, 4, 4)``, the action poses ``T_EA`` in the current EE frame, and
  ``action_gripper (B, T)`` (1 open, 0 closed).

Sizes: ``N`` demonstrations of ``L`` waypoints, ``T`` predicted actions, ``K`` DDIM steps, ``G`` gripper keypoint
nodes per gripper, ``M`` scene nodes of ``D`` features per cloud of ``P`` points, ``H`` hidden features.

Every cloud enters the encoder in its own EE frame (``T_EW · P``); only relative transforms between frames of one
world enter the graph, so the predicted relative actions do not depend on where a world is.

A control step is :meth:`InstantPolicyNetwork.encode_context` (encoder on demos and current cloud, σ on their local
graphs, φ — none of it depends on the noisy actions) followed by :meth:`~InstantPolicyNetwork.sample_actions`, which
runs only the action part (:meth:`~InstantPolicyNetwork.denoise`: σ on the action local graphs, ψ, heads) in each
of the K DDIM iterations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import nn

from ..geometry.rigid_torch import invert_rigid, mean_rigid, transform_points
from .action_diffusion import ACTION_DIM, FLOW_DIM, ActionDiffusion, points_in_action_frames
from .dense_graphs import DenseGraphs
from .encodings import encoding_dim, sinusoidal_encoding
from .geometry_encoder import GeometryEncoder
from .graph import ACTION, CURRENT, GRIPPER, StageGraphs, action_edge_dims, context_edge_dims, local_edge_dims
from .graph_transformer import HeteroGraphTransformer, fixed_weights

if TYPE_CHECKING:  # the policy's config is handed in as it is (LeRobot's pattern); only its fields are read here
    from ..configuration_instant_policy import InstantPolicyConfig



@dataclass
class DemoTensors:
    """The demonstrations as the network reads them, ``N`` of them reduced to ``L`` waypoints each, per batch row.

    Attributes:
        T_world_ee: ``(B, N, L, 4, 4)`` the waypoints' EE poses in their demonstration's world frame.
        gripper_open: ``(B, N, L)`` their gripper states, 1 open, 0 closed.
        scene_positions: ``(B, N, L, M, 3)`` the frozen encoder's scene nodes of each waypoint's cloud, in the
            waypoint's own EE frame (:meth:`InstantPolicyNetwork.encode_observation`).
        scene_features: ``(B, N, L, M, D)`` their features.
    """

    T_world_ee: torch.Tensor
    gripper_open: torch.Tensor
    scene_positions: torch.Tensor
    scene_features: torch.Tensor

    @property
    def batch_size(self) -> int:
        return self.T_world_ee.shape[0]

    @property
    def num_demos(self) -> int:
        return self.T_world_ee.shape[1]

    @property
    def num_waypoints(self) -> int:
        return self.T_world_ee.shape[2]

    def expand(self, batch_size: int) -> DemoTensors:
        """The same demonstrations for ``batch_size`` rows: a view of a batch of one (one task's context)."""
        if self.batch_size != 1:
            raise ValueError(f"only a batch of one demonstration set can be expanded, got {self.batch_size}")
        return DemoTensors(*(value.expand(batch_size, *value.shape[1:]) for value in (
            self.T_world_ee, self.gripper_open, self.scene_positions, self.scene_features)))


@dataclass
class InstantPolicyContext:
    """What one control step computes once and every denoising iteration reuses.

    Attributes:
        current_gripper_features: ``(B, G, H)`` φ's output at the current gripper nodes (the paper's bottleneck).
        points_ee: ``(B, P, 3)`` the live cloud in the current EE frame; None when the live frame came encoded
            (only ``reencode_action_clouds`` reads it).
        scene_positions_ee: ``(B, M, 3)`` the current scene nodes in the EE frame.
        scene_features: ``(B, M, D)`` their encoder features.
    """

    current_gripper_features: torch.Tensor
    points_ee: torch.Tensor | None
    scene_positions_ee: torch.Tensor
    scene_features: torch.Tensor

    @property
    def batch_size(self) -> int:
        return self.scene_positions_ee.shape[0]

    def repeat_rows(self, repeats: int) -> InstantPolicyContext:
        """Each batch row ``repeats`` times in a row: batch ``B`` → ``B · repeats`` (row ``b`` at ``b · repeats …``)."""
        return InstantPolicyContext(*(None if value is None else value.repeat_interleave(repeats, dim=0) for value in (
            self.current_gripper_features, self.points_ee, self.scene_positions_ee, self.scene_features)))


def _head(hidden_dim: int, out_dim: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(hidden_dim, hidden_dim), nn.GELU(), nn.Linear(hidden_dim, out_dim))


class InstantPolicyNetwork(nn.Module):
    """Graph-diffusion network of Instant Policy. The geometry encoder is frozen (no gradients, always eval); it is
    initialised randomly here, and the policy loads its pretrained weights (or a checkpoint's).

    Args:
        config: the policy's :class:`~lerobot_instant_policy.configuration_instant_policy.InstantPolicyConfig`, read
            for the sizes (``hidden_dim``, ``num_heads``, ``mlp_ratio``, ``local_layers``, ``context_layers``,
            ``action_layers``, ``encoder_config``, ``num_points``, ``horizon``, ``gripper_keypoints``,
            ``num_frequencies``), the diffusion (``diffusion_train_steps``, ``inference_steps``, ``max_translation``,
            ``max_rotation_deg``, ``gripper_loss_weight``), the graph (``action_scene_graph``,
            ``reencode_action_clouds``) and ``compile_model`` / ``compile_inference`` / ``compile_mode`` (σ, φ and ψ
            compiled for the training step, for sampling).

    Attributes:
        graphs: σ, φ and ψ (``local_network``, ``context_network``, ``action_network``) on their graphs in the dense
            layout (:class:`~.dense_graphs.DenseGraphs`; the torch-geometric layout
            :class:`~.sparse_graphs.SparseGraphs` is its reference, with the same weights and outputs).
    """

    def __init__(self, config: InstantPolicyConfig):
        super().__init__()
        self.config = config
        hidden, num_keypoints = config.hidden_dim, len(config.gripper_keypoints)
        self.geometry_encoder = GeometryEncoder(config.encoder_config).requires_grad_(False)
        self.register_buffer(
            "gripper_keypoints", torch.tensor(config.gripper_keypoints, dtype=torch.float32), persistent=False
        )
        self.scene_projection = nn.Linear(config.encoder_config.feature_dim, hidden)
        # Observation (demo and current) gripper nodes and action gripper nodes have separate embeddings, one per
        # keypoint and, for actions, per action step: action step 0 never shares an embedding with the current frame.
        self.observation_keypoint_embedding = nn.Embedding(num_keypoints, hidden)
        self.action_keypoint_embedding = nn.Embedding(config.horizon * num_keypoints, hidden)
        self.gripper_state_embedding = nn.Embedding(2, hidden)
        self.action_gripper_embedding = nn.Linear(1, hidden)
        self.timestep_embedding = nn.Sequential(
            nn.Linear(encoding_dim(1, config.num_frequencies), hidden), nn.GELU(), nn.Linear(hidden, hidden)
        )
        stage = dict(hidden_dim=hidden, num_heads=config.num_heads, mlp_ratio=config.mlp_ratio)
        self.local_network = HeteroGraphTransformer(
            local_edge_dims(config.num_frequencies), [GRIPPER], num_layers=config.local_layers, **stage
        )
        self.context_network = HeteroGraphTransformer(
            context_edge_dims(config.num_frequencies), [CURRENT],
            num_layers=config.context_layers, **stage
        )
        self.action_network = HeteroGraphTransformer(
            action_edge_dims(config.num_frequencies), [ACTION], num_layers=config.action_layers, **stage
        )
        self.graphs: StageGraphs = DenseGraphs(
            self.local_network, self.context_network, self.action_network, config.num_frequencies
        )
        self.translation_head = _head(hidden, 3)
        self.rotation_head = _head(hidden, 3)
        self.gripper_head = _head(hidden, 1)
        self.diffusion = ActionDiffusion(
            config.horizon,
            self.gripper_keypoints,
            config.diffusion_train_steps,
            config.max_translation,
            math.radians(config.max_rotation_deg),
        )
        if config.compile_model or config.compile_inference:
            for network in (self.local_network, self.context_network, self.action_network):
                network.compile_dense(config.compile_mode, training=config.compile_model,
                                      inference=config.compile_inference)

    def train(self, mode: bool = True) -> InstantPolicyNetwork:
        super().train(mode)
        self.geometry_encoder.eval()
        return self

    @property
    def num_keypoints(self) -> int:
        return len(self.config.gripper_keypoints)

    def _keypoints(self, like: torch.Tensor) -> torch.Tensor:
        return self.gripper_keypoints.to(dtype=like.dtype, device=like.device)

    # ------------------------------------------------------------------ input checks
    def _check_cloud(self, name: str, points: torch.Tensor, leading: tuple[int, ...]) -> None:
        expected = (*leading, self.config.num_points, 3)
        if points.ndim != len(expected) or points.shape[-1] != 3:
            raise ValueError(f"{name} must have shape {tuple(expected)}, got {tuple(points.shape)}")
        if points.shape[-2] != self.config.num_points:
            raise ValueError(
                f"{name} has {points.shape[-2]} points per cloud but the network is configured for "
                f"num_points={self.config.num_points}; resample the clouds"
            )
        if tuple(points.shape[:-2]) != tuple(leading):
            raise ValueError(f"{name} must have shape {tuple(expected)}, got {tuple(points.shape)}")
        if not torch.isfinite(points).all():
            raise ValueError(f"{name} contains NaN or inf coordinates")

    @staticmethod
    def _check_tensor(name: str, value: torch.Tensor, shape: tuple[int, ...]) -> None:
        if tuple(value.shape) != tuple(shape):
            raise ValueError(f"{name} must have shape {tuple(shape)}, got {tuple(value.shape)}")
        if not torch.isfinite(value).all():
            raise ValueError(f"{name} contains NaN or inf values")

    # ------------------------------------------------------------------ node features
    def encode_clouds(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Frozen encoder on clouds ``(..., P, 3)`` (any frame) → positions ``(..., M, 3)``, features ``(..., M, D)``
        (:meth:`GeometryEncoder.encode`: full precision, no gradients)."""
        return self.geometry_encoder.encode(points)

    def encode_observation(self, points_world: torch.Tensor, T_world_ee: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The frozen encoder on observed clouds in their own EE frames: ``points_world (..., P, 3)`` and the EE poses
        ``T_world_ee (..., 4, 4)`` → scene-node positions in the EE frame ``(..., M, 3)`` and features ``(..., M, D)``.
        The one place a frame's cloud becomes scene nodes, live, for a cache (``frame_encodings``) or for the task
        pool (:meth:`GeometryEncoder.encode_in_frames`)."""
        return self.geometry_encoder.encode_in_frames(points_world, T_world_ee)

    def observation_gripper_features(self, gripper_open: torch.Tensor) -> torch.Tensor:
        """Gripper-node features of observed frames: ``gripper_open (...)`` in {0, 1} → ``(..., G, H)``."""
        state = self.gripper_state_embedding((gripper_open > 0.5).long())
        return self.observation_keypoint_embedding.weight + state[..., None, :]

    def action_gripper_features(self, gripper: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        """Gripper-node features of actions: ``gripper (B, T)`` in [−1, 1], ``timesteps (B,)`` → ``(B, T, G, H)``."""
        keypoint = self.action_keypoint_embedding.weight.view(self.config.horizon, self.num_keypoints, -1)
        value = self.action_gripper_embedding(gripper[..., None].to(keypoint.dtype))
        phase = (timesteps.to(keypoint.dtype) / self.config.diffusion_train_steps)[:, None]
        timestep = self.timestep_embedding(sinusoidal_encoding(phase, self.config.num_frequencies))
        return keypoint + value[:, :, None] + timestep[:, None, None]

    def _local_gripper_features(
        self, scene_positions: torch.Tensor, scene_features: torch.Tensor, gripper_features: torch.Tensor
    ) -> torch.Tensor:
        """σ on R local graphs: scene nodes ``(R, M, 3)`` in each graph's EE frame, their encoder features
        ``(R, M, D)``, gripper features ``(R, G, H)`` → gripper features ``(R, G, H)``."""
        return self.graphs.local(
            scene_positions, self._scene_nodes(scene_features), gripper_features, self._keypoints(scene_positions)
        )

    def _scene_nodes(self, scene_features: torch.Tensor) -> torch.Tensor:
        """``scene_projection`` of ``(R, M, D)`` → ``(R, M, H)``. Features expanded along the graphs (one scene seen
        from the T action frames at batch 1) are projected once and stay expanded, so the dense σ projects them once
        too."""
        if scene_features.stride(0) == 0:
            return self.scene_projection(scene_features[:1]).expand(len(scene_features), -1, -1)
        return self.scene_projection(scene_features)

    # ------------------------------------------------------------------ context (once per control step)
    def encode_demo_waypoints(self, demos: DemoTensors) -> torch.Tensor:
        """σ on the demonstrations' local graphs alone → the demo gripper nodes' features ``(B, N, L, G, H)``. It
        does not depend on the live observation, so at inference it is computed once per task (and weights) and
        handed to :meth:`encode_context` at every control step."""
        self._check_demos(demos)
        leading = (demos.batch_size, demos.num_demos, demos.num_waypoints)
        return self._observation_gripper_features(
            demos.scene_positions, demos.scene_features, demos.gripper_open, leading=leading
        )

    def _check_demos(self, demos: DemoTensors) -> None:
        if demos.T_world_ee.ndim != 5:
            raise ValueError(f"demo T_world_ee must have shape (B, N, L, 4, 4), got {tuple(demos.T_world_ee.shape)}")
        leading = (demos.batch_size, demos.num_demos, demos.num_waypoints)
        self._check_tensor("demo T_world_ee", demos.T_world_ee, (*leading, 4, 4))
        self._check_tensor("demo gripper_open", demos.gripper_open, leading)
        self._check_scene_nodes("demo", demos.scene_positions, demos.scene_features, leading)

    def _check_scene_nodes(self, name: str, positions: torch.Tensor, features: torch.Tensor, leading: tuple) -> None:
        num_scene = self.config.encoder_config.num_nodes
        self._check_tensor(f"{name} scene positions", positions, (*leading, num_scene, 3))
        self._check_tensor(f"{name} scene features", features, (*leading, num_scene, self.config.encoder_config.feature_dim))

    def _observation_gripper_features(
        self, positions: torch.Tensor, features: torch.Tensor, gripper_open: torch.Tensor, leading: tuple[int, ...]
    ) -> torch.Tensor:
        """σ on observed frames ``leading``: scene nodes ``(*leading, M, 3)``, ``(*leading, M, D)`` and gripper states
        ``leading`` → gripper features ``(*leading, G, H)``."""
        out = self._local_gripper_features(
            positions.flatten(0, len(leading) - 1), features.flatten(0, len(leading) - 1),
            self.observation_gripper_features(gripper_open).flatten(0, len(leading) - 1),
        )
        return out.view(*leading, self.num_keypoints, -1)

    def encode_context(
        self,
        demos: DemoTensors,
        points_world: torch.Tensor | None,
        T_world_ee: torch.Tensor,
        gripper: torch.Tensor,
        scene_geometry: tuple[torch.Tensor, torch.Tensor] | None = None,
        demo_waypoint_features: torch.Tensor | None = None,
    ) -> InstantPolicyContext:
        """Run everything that does not depend on the noisy actions: encoder, σ on demo and current graphs, φ.

        Args:
            demos: the demonstrations of every row (:class:`DemoTensors`, batch ``B``).
            points_world: ``(B, P, 3)`` the live cloud in the world frame; None when ``scene_geometry`` is given
                and the action graphs do not re-encode the cloud (``reencode_action_clouds`` off).
            T_world_ee: ``(B, 4, 4)`` the current EE pose in the world frame.
            gripper: ``(B,)`` the current gripper state, 1 open, 0 closed.
            scene_geometry: the live cloud's scene nodes in the current EE frame, positions ``(B, M, 3)`` and
                features ``(B, M, D)`` as :meth:`encode_observation` gives them (a frame-encoding cache); None encodes
                ``points_world``.
            demo_waypoint_features: σ's output on the demonstrations' local graphs, ``(B, N, L, G, H)`` from
                :meth:`encode_demo_waypoints` with the current weights (a policy computes it once per task); None runs
                σ on them here, in one batch with the current frame (training).
        """
        self._check_demos(demos)
        batch, num_demos, demo_length = demos.batch_size, demos.num_demos, demos.num_waypoints
        self._check_tensor("T_world_ee", T_world_ee, (batch, 4, 4))
        self._check_tensor("gripper", gripper, (batch,))
        if points_world is None:
            if scene_geometry is None or (self.config.action_scene_graph and self.config.reencode_action_clouds):
                raise ValueError("points_world is needed without scene_geometry and when the action graphs re-encode "
                                 "the live cloud (reencode_action_clouds)")
            points_ee = None
        else:
            self._check_cloud("points_world", points_world, (batch,))
            points_ee = transform_points(invert_rigid(T_world_ee), points_world)
        if scene_geometry is None:
            scene_geometry = self.encode_clouds(points_ee)
        scene_positions, scene_features = scene_geometry
        self._check_scene_nodes("live", scene_positions, scene_features, (batch,))
        if demo_waypoint_features is None:
            # σ on the demo and current graphs in one batch: (B, N·L + 1, G, H).
            gripper_features = self._observation_gripper_features(
                torch.cat([demos.scene_positions.flatten(1, 2), scene_positions[:, None]], dim=1),
                torch.cat([demos.scene_features.flatten(1, 2), scene_features[:, None]], dim=1),
                torch.cat([demos.gripper_open.flatten(1, 2), gripper[:, None]], dim=1),
                leading=(batch, num_demos * demo_length + 1),
            )
        else:
            hidden = (self.num_keypoints, self.config.hidden_dim)
            self._check_tensor("demo waypoint features", demo_waypoint_features,
                               (batch, num_demos, demo_length, *hidden))
            current = self._observation_gripper_features(scene_positions, scene_features, gripper, leading=(batch,))
            gripper_features = torch.cat([demo_waypoint_features.flatten(1, 2), current[:, None]], dim=1)

        demo_features = gripper_features[:, :-1].unflatten(1, (num_demos, demo_length))
        return InstantPolicyContext(
            current_gripper_features=self._context_features(demos.T_world_ee, demo_features, gripper_features[:, -1]),
            points_ee=points_ee,
            scene_positions_ee=scene_positions,
            scene_features=scene_features,
        )

    def _context_features(
        self, T_world_ee: torch.Tensor, demo_features: torch.Tensor, current_features: torch.Tensor
    ) -> torch.Tensor:
        """φ: demo waypoint poses ``(B, N, L, 4, 4)`` in their demonstration's world frame, demo gripper nodes
        ``(B, N, L, G, H)`` and current gripper nodes ``(B, G, H)`` after σ → the current gripper nodes ``(B, G, H)``."""
        return self.graphs.context(T_world_ee, demo_features, current_features, self._keypoints(T_world_ee))

    # ------------------------------------------------------------------ action part (every denoising step)
    def denoise(
        self,
        context: InstantPolicyContext,
        T_ee_actions: torch.Tensor,
        action_gripper: torch.Tensor,
        timesteps: torch.Tensor,
    ) -> torch.Tensor:
        """Predict, per action gripper keypoint, normalised flows and the clean gripper value.

        Args:
            context: from :meth:`encode_context`.
            T_ee_actions: ``(B, T, 4, 4)`` noisy action poses in the current EE frame.
            action_gripper: ``(B, T)`` noisy gripper values in [−1, 1].
            timesteps: ``(B,)`` diffusion timesteps in ``0 … num_train_timesteps − 1``.

        Returns:
            ``(B, T, G, 7)``: translation flow (3) and rotation flow (3), normalised as in
            :meth:`ActionDiffusion.flow_targets`, then the logit of the clean gripper command being "open".
        """
        batch, horizon = context.batch_size, self.config.horizon
        self._check_tensor("T_ee_actions", T_ee_actions, (batch, horizon, 4, 4))
        self._check_tensor("action_gripper", action_gripper, (batch, horizon))
        gripper_features = self.action_gripper_features(action_gripper, timesteps)
        if self.config.action_scene_graph:
            if self.config.reencode_action_clouds:
                points_actions = points_in_action_frames(context.points_ee, T_ee_actions)
                scene_positions, scene_features = self.encode_clouds(points_actions)
            else:
                scene_positions = points_in_action_frames(context.scene_positions_ee, T_ee_actions)
                scene_features = context.scene_features[:, None].expand(-1, horizon, -1, -1)
            gripper_features = self._local_gripper_features(
                scene_positions.flatten(0, 1), scene_features.flatten(0, 1), gripper_features.flatten(0, 1)
            ).unflatten(0, (batch, horizon))
        actions = self.graphs.actions(
            T_ee_actions, context.current_gripper_features, gripper_features, self._keypoints(T_ee_actions)
        )
        out = torch.cat([self.translation_head(actions), self.rotation_head(actions), self.gripper_head(actions)], -1)
        # float32 even when the layers ran under autocast: the diffusion's geometry is done in full precision.
        return out.float()

    def training_loss(
        self,
        context: InstantPolicyContext,
        T_ee_actions: torch.Tensor,
        action_gripper: torch.Tensor,
        generator: torch.Generator | None = None,
        prior: torch.Tensor | None = None,
        refined_rows: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Noise the actions at random timesteps and regress the flows and gripper at the action gripper nodes.

        Training to refine: the rows ``refined_rows`` noise the ``prior`` instead of the clean actions, at a timestep
        drawn from the first ``⌈refine_max_strength · diffusion_train_steps⌉`` (those where inference from a noised
        prior starts), and regress the same targets, the flows from that noisy sample to the clean actions. The
        forward process (DDPM, Ho et al. 2020, eq. 4) is the same, ``xₖ = √ᾱₖ x̃ + √(1−ᾱₖ) ε``, its ``x̃`` the
        prior where the paper's is the clean ``x₀``.

        Args:
            T_ee_actions: ``(B, T, 4, 4)`` clean action poses in the current EE frame (clamped to the bounds).
            action_gripper: ``(B, T)`` gripper commands, 1 open, 0 closed.
            prior: ``(B, T, 7)`` a guess of the diffusion variable (:meth:`ActionDiffusion.normalize` of the replay
                prior in the current EE frame), or None (every row the paper's loss).
            refined_rows: ``(B,)`` bool, with ``prior``: the rows that start from it.

        Returns:
            ``loss`` = translation + rotation + ``gripper_loss_weight`` · gripper, and its parts: ``translation`` and
            ``rotation`` (mean squared errors of the normalised flows, every timestep weighted alike, as in the paper)
            and ``gripper`` (binary cross-entropy of the gripper logits against the clean command). The flows drive the gradients: the gripper is a binary label
            that a cross-entropy learns fast, while its squared error on ±1 targets dominated the sum.
        """
        batch, horizon = context.batch_size, self.config.horizon
        self._check_tensor("T_ee_actions", T_ee_actions, (batch, horizon, 4, 4))
        self._check_tensor("action_gripper", action_gripper, (batch, horizon))
        device = T_ee_actions.device
        noise_device = generator.device if generator is not None else device
        clean = self.diffusion.normalize(T_ee_actions, action_gripper)
        timesteps = torch.randint(
            0, self.config.diffusion_train_steps, (batch,), generator=generator, device=noise_device
        ).to(device)
        noise = torch.randn(clean.shape, generator=generator, device=noise_device, dtype=clean.dtype).to(device)
        start = clean
        if prior is not None:
            self._check_tensor("prior", prior, (batch, horizon, ACTION_DIM))
            self._check_tensor("refined_rows", refined_rows, (batch,))
            refine_steps = math.ceil(self.config.refine_max_strength * self.config.diffusion_train_steps)
            refine_timesteps = torch.randint(0, refine_steps, (batch,), generator=generator, device=noise_device)
            timesteps = torch.where(refined_rows, refine_timesteps.to(device), timesteps)
            start = torch.where(refined_rows[:, None, None], prior.to(clean.dtype).clamp(-1.0, 1.0), clean)
        T_noisy, gripper_noisy = self.diffusion.unnormalize(self.diffusion.add_noise(start, noise, timesteps))
        T_clean, _ = self.diffusion.unnormalize(clean)
        flow_target = self.diffusion.flow_targets(T_clean, T_noisy)
        prediction = self.denoise(context, T_noisy, gripper_noisy, timesteps)
        squared = (prediction[..., :FLOW_DIM] - flow_target).square()  # (B, T, G, 6)
        translation = squared[..., :3].mean(dim=(1, 2, 3)).mean()
        rotation = squared[..., 3:].mean(dim=(1, 2, 3)).mean()
        gripper_open = (clean[..., 6:7] > 0).to(prediction.dtype).expand_as(prediction[..., 6])
        gripper = nn.functional.binary_cross_entropy_with_logits(prediction[..., 6], gripper_open)
        loss = translation + rotation + self.config.gripper_loss_weight * gripper
        return {"loss": loss, "translation": translation, "rotation": rotation, "gripper": gripper}

    def _denoise_to_values(self, context, T_noisy, gripper, timesteps) -> torch.Tensor:
        """:meth:`denoise` with the gripper logit turned into the clean value's estimate ``2 σ(logit) − 1`` in [−1, 1]
        (the posterior mean of a ±1 variable), as the DDIM step expects."""
        prediction = self.denoise(context, T_noisy, gripper, timesteps)
        return torch.cat([prediction[..., :FLOW_DIM], 2.0 * torch.sigmoid(prediction[..., FLOW_DIM:]) - 1.0], dim=-1)

    @torch.no_grad()
    def sample_actions(
        self,
        context: InstantPolicyContext,
        generator: torch.Generator | None = None,
        num_inference_steps: int | None = None,
        initial: torch.Tensor | None = None,
        strength: float = 1.0,
        num_samples: int = 1,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """DDIM-sample the actions, from pure noise or from a noised guess ``initial (B, T, 7)`` (the diffusion
        variable of :meth:`ActionDiffusion.normalize`) with ``strength`` (:meth:`ActionDiffusion.sample`).

        With ``num_samples`` S > 1 (beyond the paper) each row is sampled S times from S noise draws, as
        one batch of ``B · S`` rows, and the samples are averaged: per action the mean pose
        (:func:`~..geometry.rigid_torch.mean_rigid`: mean translation, chordal mean rotation) and the sign of the
        mean gripper variable. S = 1 is the paper's single sample.

        Returns:
            ``T_ee_actions (B, T, 4, 4)``: action poses in the current EE frame; ``gripper_open (B, T)`` in {0, 1}.
        """
        steps = self.config.inference_steps if num_inference_steps is None else num_inference_steps
        if num_samples > 1:
            context = context.repeat_rows(num_samples)
            initial = None if initial is None else initial.repeat_interleave(num_samples, dim=0)
        with fixed_weights(self):
            sample = self.diffusion.sample(
                lambda T_noisy, gripper, timesteps: self._denoise_to_values(context, T_noisy, gripper, timesteps),
                context.batch_size,
                steps,
                generator=generator,
                device=context.scene_positions_ee.device,
                dtype=context.scene_positions_ee.dtype,
                initial=initial,
                strength=strength,
            )
        T_ee_actions, gripper = self.diffusion.unnormalize(sample)
        if num_samples > 1:
            T_ee_actions = mean_rigid(T_ee_actions.unflatten(0, (-1, num_samples)), dim=1)
            gripper = gripper.unflatten(0, (-1, num_samples)).mean(dim=1)
        return T_ee_actions, (gripper > 0).to(sample.dtype)
