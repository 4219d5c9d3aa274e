"""``DoNothingConfig``: the configuration of the ``do_nothing`` baseline policy (``--policy.type=do_nothing``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PolicyFeature, PreTrainedConfig

from ..contract import ACTION_KEY, STATE_KEY
from ..policy.features import contract_input_features, contract_output_features, identity_normalization
from .untrained import UntrainedPolicyConfigMixin


@PreTrainedConfig.register_subclass("do_nothing")
@dataclass
class DoNothingConfig(UntrainedPolicyConfigMixin, PreTrainedConfig):
    """The lower-bound baseline: command the current EE pose and gripper state, so the robot holds still.

    The action ``(8,)`` is ``observation.state (8,)`` unchanged (EE xyz, quaternion xyzw in the world frame, then
    ``gripper_open`` read as the gripper command). It reads no demonstrations and no point cloud, and has no
    parameters; a task that a do-nothing policy "solves" is a task whose success check is broken.

    The features default to the package's data contract (``observation.pointcloud``, ``observation.state``,
    ``action``) with IDENTITY normalisation, like ``instant_policy`` and ``demo_replay``; only the state and the
    action are required.
    """

    push_to_hub: bool = False

    input_features: dict[str, PolicyFeature] | None = field(default_factory=contract_input_features)
    output_features: dict[str, PolicyFeature] | None = field(default_factory=contract_output_features)
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_obs_steps != 1:
            raise ValueError(f"do_nothing reads the current observation only: n_obs_steps must be 1, got {self.n_obs_steps}")

    def validate_features(self) -> None:
        """The policy reads ``observation.state (8,)`` and writes ``action (8,)`` of the same layout."""
        state = (self.input_features or {}).get(STATE_KEY)
        action = (self.output_features or {}).get(ACTION_KEY)
        problems = []
        if state is None or tuple(state.shape) != (8,):
            problems.append(f"input {STATE_KEY!r} of shape (8,), got {tuple(state.shape) if state else 'nothing'}")
        if action is None or tuple(action.shape) != (8,):
            problems.append(f"output {ACTION_KEY!r} of shape (8,), got {tuple(action.shape) if action else 'nothing'}")
        if problems:
            raise ValueError("do_nothing needs " + "; ".join(problems))
