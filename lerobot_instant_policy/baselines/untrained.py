"""What LeRobot asks of a policy config that is never trained (the baselines): no optimiser steps, no scheduler,
no temporal context."""

from __future__ import annotations

from lerobot.optim import AdamWConfig


class UntrainedPolicyConfigMixin:
    """Put before ``PreTrainedConfig`` in the bases of a baseline's config: a zero learning rate, no scheduler, and
    only the current frame as observation, action and reward (``None`` delta indices)."""

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(lr=0.0)

    def get_scheduler_preset(self) -> None:
        return None

    @property
    def observation_delta_indices(self) -> None:
        return None

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None
