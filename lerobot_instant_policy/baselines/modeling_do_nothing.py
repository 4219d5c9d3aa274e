"""``DoNothingPolicy``: the lower-bound baseline: hold the current pose.

Every step it commands the pose the EE is at and the gripper state it has: ``action = observation.state``
(``(B, 8)``: EE xyz in metres and quaternion xyzw in the world frame, then ``gripper_open``, 1 open, 0 closed,
which the env reads as the gripper command). Its success rate is what a task gives for free.
"""

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor

from ..contract import STATE_KEY
from .configuration_do_nothing import DoNothingConfig
from .untrained import ParameterFreePolicyMixin


class DoNothingPolicy(ParameterFreePolicyMixin, PreTrainedPolicy):
    """Hold the current EE pose and gripper state; no parameters, nothing to train (see ``DoNothingConfig``)."""

    config_class = DoNothingConfig
    name = "do_nothing"

    def __init__(self, config: DoNothingConfig, dataset_stats=None, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config: DoNothingConfig = config

    def reset(self) -> None:
        """Nothing to clear: every action depends on the current observation only."""

    def get_optim_params(self) -> list:
        return []

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict | None]:
        raise RuntimeError("do_nothing has no trainable parameters: evaluate it with lerobot-eval, do not train it")

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """A chunk of one action ``(B, 1, 8)``: the current state."""
        return self.select_action(batch)[:, None]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Action ``(B, 8)`` float32: a copy of ``batch['observation.state'] (B, 8)`` (absolute EE pose + gripper)."""
        if STATE_KEY not in batch:
            raise KeyError(f"do_nothing needs {STATE_KEY!r} in the batch, got keys {sorted(batch)}")
        state = batch[STATE_KEY]
        if not isinstance(state, Tensor) or state.ndim != 2 or state.shape[1] != 8:
            shape = tuple(state.shape) if isinstance(state, Tensor) else type(state).__name__
            raise ValueError(f"do_nothing needs {STATE_KEY!r} of shape (B, 8) (EE xyz, quat xyzw, gripper), got {shape}")
        if not state.is_floating_point():
            raise ValueError(f"do_nothing needs a floating-point {STATE_KEY!r}, got {state.dtype}")
        return state.to(dtype=torch.float32, copy=True)
