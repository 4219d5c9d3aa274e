"""``MetaworldExpertConfig``: the configuration of the ``metaworld_expert`` policy (``--policy.type=metaworld_expert``),
MetaWorld's scripted expert of each task as a LeRobot policy: the upper bound of the MetaWorld table."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PolicyFeature, PreTrainedConfig

from ..contract import ACTION_KEY, POSE_GRIPPER_SHAPE, STATE_KEY
from ..policy.features import contract_output_features, identity_normalization
from .untrained import UntrainedPolicyConfigMixin

ENVIRONMENT_STATE_KEY = "observation.environment_state"
ENVIRONMENT_STATE_SHAPE = (39,)


def expert_input_features() -> dict[str, PolicyFeature]:
    """The EE state of the data contract and MetaWorld's own 39-number state vector."""
    return {
        STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=POSE_GRIPPER_SHAPE),
        ENVIRONMENT_STATE_KEY: PolicyFeature(type=FeatureType.ENV, shape=ENVIRONMENT_STATE_SHAPE),
    }


@PreTrainedConfig.register_subclass("metaworld_expert")
@dataclass
class MetaworldExpertConfig(UntrainedPolicyConfigMixin, PreTrainedConfig):
    """MetaWorld's scripted policy of the batch row's task (LeRobot's ``TASK_POLICY_MAPPING``), run on
    ``observation.environment_state (39,)`` (MetaWorld's privileged state: hand, fingers, object poses, goal) and
    turned into the contract's absolute EE target from ``observation.state (8,)`` (``sim.metaworld.actions``).
    ``action_scale``: MetaWorld's metres per unit of action (0.01 in every v3 task). It reads no point cloud and no
    demonstrations, and needs the ``metaworld`` extra and ``--env.type=metaworld_pointcloud``.
    """

    action_scale: float = 0.01
    push_to_hub: bool = False

    input_features: dict[str, PolicyFeature] | None = field(default_factory=expert_input_features)
    output_features: dict[str, PolicyFeature] | None = field(default_factory=contract_output_features)
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_obs_steps != 1:
            raise ValueError(f"metaworld_expert reads the current observation only: n_obs_steps must be 1, got "
                             f"{self.n_obs_steps}")
        if self.action_scale <= 0:
            raise ValueError(f"action_scale must be positive, got {self.action_scale}")

    def validate_features(self) -> None:
        """The policy reads ``observation.state (8,)`` and ``observation.environment_state (39,)`` and writes
        ``action (8,)``."""
        inputs, outputs = self.input_features or {}, self.output_features or {}
        needed = {STATE_KEY: (inputs, POSE_GRIPPER_SHAPE), ENVIRONMENT_STATE_KEY: (inputs, ENVIRONMENT_STATE_SHAPE),
                  ACTION_KEY: (outputs, POSE_GRIPPER_SHAPE)}
        problems = [f"{key!r} of shape {shape}, got {tuple(features[key].shape) if key in features else 'nothing'}"
                    for key, (features, shape) in needed.items()
                    if key not in features or tuple(features[key].shape) != shape]
        if problems:
            raise ValueError("metaworld_expert needs " + "; ".join(problems) + " (run it in --env.type=metaworld_pointcloud)")
