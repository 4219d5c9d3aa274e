"""What LeRobot asks of a baseline that is never trained: of its config, no optimiser steps, no scheduler, no
temporal context; of its policy, a checkpoint without parameters that saves and loads like any other."""

from __future__ import annotations

from pathlib import Path

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


class ParameterFreePolicyMixin:
    """Put before ``PreTrainedPolicy`` in the bases of a baseline without parameters: ``save_pretrained`` writes its
    ``config.json`` and an empty ``model.safetensors`` whether or not it is handed a state dict, and
    ``from_pretrained`` also loads a folder without the weights file.

    LeRobot writes a handed-in state dict (``lerobot-train``'s checkpoints, ``push_to_hub``) with
    ``save_torch_state_dict``, which writes no file for an empty one, and then reads ``model.safetensors`` back."""

    def _save_pretrained(self, save_directory: Path, state_dict: dict | None = None) -> None:
        if state_dict:
            raise ValueError(f"{type(self).__name__} has no parameters, got a state dict of {sorted(state_dict)[:5]}")
        super()._save_pretrained(save_directory)

    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        if not Path(model_file).is_file():
            return model
        return super()._load_as_safetensor(model, model_file, map_location, strict)
