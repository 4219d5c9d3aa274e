"""``DemoReplayConfig``: the configuration of the ``demo_replay`` baseline policy (``--policy.type=demo_replay``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PolicyFeature, PreTrainedConfig

from ..geometry.registration import RegistrationConfig
from ..policy.features import (
    check_policy_features,
    contract_input_features,
    contract_output_features,
    identity_normalization,
)
from ..replay.plan import replay_plan_name
from .untrained import UntrainedPolicyConfigMixin


@PreTrainedConfig.register_subclass("demo_replay")
@dataclass
class DemoReplayConfig(UntrainedPolicyConfigMixin, PreTrainedConfig):
    """Replay a demonstration, moved to where the task objects are now.

    At the start of an episode the policy registers the first-frame point cloud of each of ``num_demos``
    demonstrations of the env's task onto the current point cloud (principal axes + trimmed ICP, see
    ``geometry.registration``), keeps the demonstration that fits best and replays its actions (absolute EE poses
    and gripper commands) moved by the estimated ``T_now_demo``.

    Demonstrations: the episodes whose ``task`` is the env's task string in the LeRobotDataset ``demo_repo_id``
    stored at ``demo_root`` (read offline; when ``demo_root`` is unset, LeRobot's local cache
    ``$HF_LEROBOT_HOME/<demo_repo_id>``), or handed in from Python with ``DemoReplayPolicy.set_demonstrations``.

    Registration: ``registration_yaw_only`` restricts the estimated motion to a yaw about world z plus a
    translation (tabletop objects); ``registration_overlap`` is the fraction of correspondences ICP keeps;
    ``registration_points`` caps the points used in the final ICP.

    Plan (the options of ``instant_policy``'s replay, named alike): ``replay_per_object`` splits the clouds into
    objects and lets the grasp follow the grasped object and the release the other one, for tasks whose two objects
    move independently (:func:`~..replay.plan.plan_replay`); ``replay_anchored`` cuts every demonstration into
    segments at gripper changes, stops and turns and lets each segment follow the object it approaches
    (:mod:`~..replay.segments`); ``replay_consensus`` plans all three and executes the plan whose demonstrations
    agree best in the live scene; all ``False``: one motion for the whole cloud.
    """

    demo_repo_id: str | None = None
    demo_root: str | None = None
    num_demos: int = 2

    registration_yaw_only: bool = True
    registration_overlap: float = 0.8
    registration_points: int = 1024
    replay_per_object: bool = False
    replay_anchored: bool = False
    replay_consensus: bool = False

    push_to_hub: bool = False

    input_features: dict[str, PolicyFeature] | None = field(default_factory=contract_input_features)
    output_features: dict[str, PolicyFeature] | None = field(default_factory=contract_output_features)
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=identity_normalization)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_demos < 1:
            raise ValueError(f"num_demos must be at least 1, got {self.num_demos}")
        if self.n_obs_steps != 1:
            raise ValueError(f"demo_replay reads the current observation only: n_obs_steps must be 1, got {self.n_obs_steps}")
        self.registration_config()
        self.replay_plan()

    def registration_config(self) -> RegistrationConfig:
        """The ``RegistrationConfig`` these fields describe (validated)."""
        return RegistrationConfig(
            yaw_only=self.registration_yaw_only,
            overlap=self.registration_overlap,
            fine_points=self.registration_points,
        )

    def replay_plan(self) -> str:
        """The replay plan ``replay_per_object``, ``replay_anchored`` and ``replay_consensus`` name
        (:data:`~..replay.plan.REPLAY_PLANS`)."""
        return replay_plan_name(self.replay_per_object, self.replay_anchored, self.replay_consensus)

    def validate_features(self) -> None:
        """The policy reads ``observation.pointcloud (P, 3)`` and ``observation.state (8,)`` and writes ``action (8,)``."""
        check_policy_features("demo_replay", self.input_features, self.output_features)
