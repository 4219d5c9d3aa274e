"""Diffusion over relative end-effector actions in a normalised SE(3) tangent space (paper §3.2, appendices B, E).

An action ``j = 1 … T`` is ``T_EA`` (the action pose in the current EE frame E) plus a gripper command. Its
diffusion variable is 7 numbers in ``[−1, 1]``: the translation divided by ``max_translation · j``, the rotation
vector (axis-angle) divided by ``max_rotation · j`` (both clamped), and the gripper as ``−1`` (closed) or ``1``
(open). Noise follows ``diffusers``' DDPM with the squared-cosine schedule; inference is DDIM on the same schedule.

The network does not predict noise: per gripper keypoint of an action it predicts the flow that moves the keypoint
to its clean position, split into a translation part ``t⁰ − tᵏ`` and a rotation part ``R⁰ p − Rᵏ p`` (both in the
E frame, normalised separately). An SVD fit (Arun / Kabsch, :func:`~..geometry.rigid_torch.fit_rigid`, the solution of
``roma.rigid_points_registration``) turns the predicted clean keypoints into the SE(3) update of each action; its
normalised tangent is the DDIM ``sample`` prediction.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import roma
import torch
from diffusers import DDIMScheduler, DDPMScheduler

from ..geometry.rigid_torch import compose, fit_rigid, full_precision, make_rigid

ACTION_DIM = 7  # translation 3, rotation vector 3, gripper 1
FLOW_DIM = 6  # translation flow 3, rotation flow 3


@full_precision()
def points_in_action_frames(points_ee: torch.Tensor, T_ee_actions: torch.Tensor) -> torch.Tensor:
    """Re-express points given in the current EE frame E in every action frame A: ``p_A = Rᵀ (p_E − t)``.

    Args:
        points_ee: ``(B, P, 3)`` in the EE frame.
        T_ee_actions: ``(B, T, 4, 4)``, the action poses ``T_EA = (R, t)`` in the EE frame.

    Returns:
        ``(B, T, P, 3)``: the points in each action frame.
    """
    R = T_ee_actions[..., :3, :3]
    t = T_ee_actions[..., :3, 3]
    return (points_ee[:, None] - t[:, :, None]) @ R


class ActionDiffusion:
    """Normalisation, noising, flow targets and DDIM sampling of ``T`` relative actions.

    Args:
        horizon: ``T``, the number of predicted actions.
        keypoints: ``(G, 3)`` gripper keypoints in the EE frame (metres).
        num_train_timesteps: diffusion steps of the training schedule.
        max_translation: metres per action step (action ``j`` is bounded by ``j · max_translation`` per axis).
        max_rotation: radians per action step (rotation-vector components bounded by ``j · max_rotation``).
    """

    def __init__(
        self,
        horizon: int,
        keypoints: torch.Tensor,
        num_train_timesteps: int = 100,
        max_translation: float = 0.01,
        max_rotation: float = math.radians(3.0),
    ):
        self.horizon = horizon
        self.keypoints = keypoints
        self.num_train_timesteps = num_train_timesteps
        steps = torch.arange(1, horizon + 1, dtype=torch.float64)
        self.translation_bound = steps * max_translation  # (T,)
        self.rotation_bound = steps * max_rotation  # (T,)
        # Flows are differences of two clamped poses: at most twice the bound, so these scales map them to ~[−1, 1].
        self.translation_flow_scale = 2.0 * self.translation_bound
        self.rotation_flow_scale = 2.0 * self.rotation_bound * float(keypoints.norm(dim=-1).max())
        schedule = dict(
            num_train_timesteps=num_train_timesteps,
            beta_schedule="squaredcos_cap_v2",
            prediction_type="sample",
            clip_sample=False,
        )
        self.train_scheduler = DDPMScheduler(**schedule)
        self.inference_scheduler = DDIMScheduler(**schedule, set_alpha_to_one=True, timestep_spacing="trailing")

    def _per_step(self, values: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        return values.to(dtype=like.dtype, device=like.device)

    @full_precision()
    def normalize_poses(self, T_ee_actions: torch.Tensor) -> torch.Tensor:
        """``T_ee_actions (B, T, 4, 4)`` → clamped normalised tangent ``(B, T, 6)`` (translation, rotation vector)."""
        translation = T_ee_actions[..., :3, 3] / self._per_step(self.translation_bound, T_ee_actions)[:, None]
        rotation = roma.rotmat_to_rotvec(T_ee_actions[..., :3, :3])
        rotation = rotation / self._per_step(self.rotation_bound, T_ee_actions)[:, None]
        return torch.cat([translation, rotation], dim=-1).clamp(-1.0, 1.0)

    def normalize(self, T_ee_actions: torch.Tensor, gripper_open: torch.Tensor) -> torch.Tensor:
        """``T_ee_actions (B, T, 4, 4)``, ``gripper_open (B, T)`` in [0, 1] → clamped diffusion variable ``(B, T, 7)``."""
        gripper = 2.0 * gripper_open.to(T_ee_actions.dtype) - 1.0
        return torch.cat([self.normalize_poses(T_ee_actions), gripper[..., None]], dim=-1)

    def unnormalize(self, sample: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Diffusion variable ``(B, T, 7)`` → ``T_ee_actions (B, T, 4, 4)``, gripper value ``(B, T)`` in [−1, 1]."""
        sample = sample.clamp(-1.0, 1.0)
        translation = sample[..., :3] * self._per_step(self.translation_bound, sample)[:, None]
        rotation = sample[..., 3:6] * self._per_step(self.rotation_bound, sample)[:, None]
        return make_rigid(roma.rotvec_to_rotmat(rotation), translation), sample[..., 6]

    def add_noise(self, clean: torch.Tensor, noise: torch.Tensor, timesteps: torch.Tensor) -> torch.Tensor:
        """Forward process ``√ᾱ x₀ + √(1−ᾱ) ε`` at ``timesteps (B,)``, clamped to the normalised range."""
        return self.train_scheduler.add_noise(clean, noise, timesteps).clamp(-1.0, 1.0)

    @full_precision()
    def action_keypoints(self, T_ee_actions: torch.Tensor) -> torch.Tensor:
        """Gripper keypoints of each action in the EE frame: ``(B, T, 4, 4)`` → ``(B, T, G, 3)``."""
        keypoints = self.keypoints.to(dtype=T_ee_actions.dtype, device=T_ee_actions.device)
        return keypoints @ T_ee_actions[..., :3, :3].transpose(-1, -2) + T_ee_actions[..., None, :3, 3]

    @full_precision()
    def flow_targets(self, T_clean: torch.Tensor, T_noisy: torch.Tensor) -> torch.Tensor:
        """Normalised flows from the noisy to the clean keypoints, ``(B, T, G, 6)``: translation, then rotation part."""
        keypoints = self.keypoints.to(dtype=T_clean.dtype, device=T_clean.device)
        translation = (T_clean[..., :3, 3] - T_noisy[..., :3, 3])[:, :, None].expand(-1, -1, len(keypoints), -1)
        rotation = keypoints @ (T_clean[..., :3, :3] - T_noisy[..., :3, :3]).transpose(-1, -2)
        translation = translation / self._per_step(self.translation_flow_scale, T_clean)[:, None, None]
        rotation = rotation / self._per_step(self.rotation_flow_scale, T_clean)[:, None, None]
        return torch.cat([translation, rotation], dim=-1)

    @full_precision()
    def predicted_clean_actions(self, T_noisy: torch.Tensor, flows: torch.Tensor) -> torch.Tensor:
        """Apply predicted normalised flows ``(B, T, G, 6)`` to the keypoints of ``T_noisy (B, T, 4, 4)``.

        The SE(3) update that best moves the noisy keypoints onto the predicted ones (SVD) is composed with the
        noisy action: ``T̂⁰_EA = T_update · Tᵏ_EA`` (both in the EE frame).
        """
        noisy_keypoints = self.action_keypoints(T_noisy)
        translation = flows[..., :3] * self._per_step(self.translation_flow_scale, flows)[:, None, None]
        rotation = flows[..., 3:6] * self._per_step(self.rotation_flow_scale, flows)[:, None, None]
        R_update, t_update = fit_rigid(noisy_keypoints, noisy_keypoints + translation + rotation)
        return compose(make_rigid(R_update, t_update), T_noisy)

    def sample(
        self,
        predict: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor],
        batch_size: int,
        num_inference_steps: int,
        generator: torch.Generator | None = None,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        initial: torch.Tensor | None = None,
        strength: float = 1.0,
    ) -> torch.Tensor:
        """DDIM to a clean diffusion variable ``(B, T, 7)``, from Gaussian noise or from a noised guess.

        Args:
            predict: ``(T_ee_actions (B, T, 4, 4), gripper (B, T) in [−1, 1], timesteps (B,)) → (B, T, G, 7)``, the
                network's normalised flows and gripper predictions at each action keypoint.
            num_inference_steps: K, between 1 and ``num_train_timesteps``.
            initial: ``(B, T, 7)``, a clean guess of the diffusion variable (e.g. :meth:`normalize` of demonstrated
                actions replayed into the live scene), or None for the paper's start from pure noise.
            strength: with ``initial``, the fraction of the K steps that run (SDEdit, Meng et al. 2022, as in
                diffusers' image-to-image pipelines): the guess is noised by the forward process to the timestep of
                the last ``⌈strength · K⌉`` steps and denoised through them only. 1: from almost pure noise (the
                guess keeps ``√ᾱ`` of the first timestep); small: close to the guess.
        """
        if not 1 <= num_inference_steps <= self.num_train_timesteps:
            raise ValueError(
                f"num_inference_steps must be in 1…{self.num_train_timesteps}, got {num_inference_steps}"
            )
        if not 0.0 < strength <= 1.0:
            raise ValueError(f"strength must lie in (0, 1], got {strength}")
        shape = (batch_size, self.horizon, ACTION_DIM)
        if initial is not None and tuple(initial.shape) != shape:
            raise ValueError(f"initial must have shape (B, T, 7) = {shape}, got {tuple(initial.shape)}")
        noise_device = generator.device if generator is not None else device
        noise = torch.randn(shape, generator=generator, device=noise_device, dtype=dtype).to(device)
        self.inference_scheduler.set_timesteps(num_inference_steps)
        timesteps = self.inference_scheduler.timesteps.tolist()
        if initial is None:
            sample = noise.clamp(-1.0, 1.0)
        else:
            timesteps = timesteps[num_inference_steps - math.ceil(strength * num_inference_steps):]
            start = torch.full((batch_size,), timesteps[0], device=device, dtype=torch.long)
            sample = self.add_noise(initial.to(device=device, dtype=dtype).clamp(-1.0, 1.0), noise, start)
        for timestep in timesteps:
            T_noisy, gripper = self.unnormalize(sample)
            prediction = predict(T_noisy, gripper, torch.full((batch_size,), timestep, device=device))
            T_clean = self.predicted_clean_actions(T_noisy, prediction[..., :FLOW_DIM])
            gripper_clean = prediction[..., FLOW_DIM].mean(dim=-1)
            clean = torch.cat([self.normalize_poses(T_clean), gripper_clean.clamp(-1.0, 1.0)[..., None]], dim=-1)
            sample = self.inference_scheduler.step(clean, timestep, sample, eta=0.0).prev_sample.clamp(-1.0, 1.0)
        return sample
