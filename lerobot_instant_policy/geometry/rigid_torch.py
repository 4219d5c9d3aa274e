"""Rigid transforms in torch, always in full precision.

Poses are ``(..., 4, 4)`` homogeneous matrices named ``T_<to>_<from>`` as in :mod:`.se3` (their numpy counterparts).
Under ``--policy.use_amp`` LeRobot runs the policy inside ``torch.autocast``, which would run every matrix product
in bfloat16 (on the CPU) or float16: a coordinate of 0.5 m would then be off by up to 2 mm, and the finest edge
encodings (``2⁹ π`` rad/m) would be noise. Every function here therefore runs with autocast off
(:func:`full_precision`), and so does every other piece of geometry in the model (edge attributes, action frames,
the diffusion's SE(3) fits): only the network's layers run in reduced precision.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import roma
import torch

_AUTOCAST_DEVICES = ("cpu", "cuda")


@contextlib.contextmanager
def full_precision() -> Iterator[None]:
    """Turn autocast off on the CPU and CUDA inside the block (a decorator too: ``@full_precision()``). Inputs keep
    their dtype: give float32 (or float64) tensors."""
    with contextlib.ExitStack() as stack:
        for device_type in _AUTOCAST_DEVICES:
            if torch.is_autocast_enabled(device_type):
                stack.enter_context(torch.autocast(device_type, enabled=False))
        yield


@full_precision()
def invert_rigid(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms ``(..., 4, 4)``."""
    R_inv = T[..., :3, :3].transpose(-1, -2)
    inverse = torch.zeros_like(T)
    inverse[..., :3, :3] = R_inv
    inverse[..., :3, 3] = -(R_inv @ T[..., :3, 3:4]).squeeze(-1)
    inverse[..., 3, 3] = 1.0
    return inverse


def make_rigid(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """``R (..., 3, 3)``, ``t (..., 3)`` → ``(..., 4, 4)``."""
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


@full_precision()
def compose(T_a_b: torch.Tensor, T_b_c: torch.Tensor) -> torch.Tensor:
    """``T_a_c = T_a_b · T_b_c`` for broadcastable ``(..., 4, 4)`` stacks."""
    return T_a_b @ T_b_c


@full_precision()
def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``T (..., 4, 4)`` applied to ``points (..., P, 3)``: ``R p + t`` per point."""
    return points @ T[..., :3, :3].transpose(-1, -2) + T[..., None, :3, 3]


@full_precision()
def fit_rigid(source: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The rigid transform that best maps points ``source (..., Q, 3)`` onto ``target (..., Q, 3)`` in the least-squares
    sense (Kabsch / Arun: an SVD of the 3 × 3 cross-covariance, in float64, with the reflection removed).

    Returns ``R (..., 3, 3)`` and ``t (..., 3)`` with ``target ≈ R source + t``, in ``source``'s dtype: the solution of
    ``roma.rigid_points_registration`` (to float precision, tested), several times faster on small batches.
    """
    source_mean, target_mean = source.mean(dim=-2, keepdim=True), target.mean(dim=-2, keepdim=True)
    covariance = ((target - target_mean).transpose(-1, -2) @ (source - source_mean)).double()
    U, _, Vh = torch.linalg.svd(covariance)
    reflection = torch.det(U @ Vh).sign()
    U = torch.cat([U[..., :2], U[..., 2:] * reflection[..., None, None]], dim=-1)
    R = (U @ Vh).to(source.dtype)
    return R, (target_mean - source_mean @ R.transpose(-1, -2)).squeeze(-2)


@full_precision()
def mean_rigid(T: torch.Tensor, dim: int) -> torch.Tensor:
    """The mean of rigid transforms ``(..., 4, 4)`` over batch dimension ``dim``: the mean translation, and the
    chordal L2 mean rotation (the rotation nearest in Frobenius norm to the mean rotation matrix,
    ``roma.special_procrustes``). Left-multiplying every transform by one rigid ``G`` multiplies the mean by ``G``."""
    rotation = roma.special_procrustes(T[..., :3, :3].mean(dim=dim))
    return make_rigid(rotation, T[..., :3, 3].mean(dim=dim))
