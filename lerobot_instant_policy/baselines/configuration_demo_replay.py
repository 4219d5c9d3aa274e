"""``DemoReplayConfig``: the configuration of the ``demo_replay`` baseline policy (``--policy.type=demo_replay``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import FeatureType, NormalizationMode, PolicyFeature, PreTrainedConfig
from lerobot.optim import AdamWConfig

from ..data.lerobot_format import ACTION_KEY, NUM_POINTS, POINTCLOUD_KEY, STATE_KEY
from ..geometry.registration import RegistrationConfig


@PreTrainedConfig.register_subclass("demo_replay")
@dataclass
class DemoReplayConfig(PreTrainedConfig):
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
    """

    demo_repo_id: str | None = None
    demo_root: str | None = None
    num_demos: int = 2

    registration_yaw_only: bool = True
    registration_overlap: float = 0.8
    registration_points: int = 1024

    push_to_hub: bool = False

    input_features: dict[str, PolicyFeature] | None = field(
        default_factory=lambda: {
            POINTCLOUD_KEY: PolicyFeature(type=FeatureType.STATE, shape=(NUM_POINTS, 3)),
            STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(8,)),
        }
    )
    output_features: dict[str, PolicyFeature] | None = field(
        default_factory=lambda: {ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(8,))}
    )
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.IDENTITY,
        }
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.num_demos < 1:
            raise ValueError(f"num_demos must be at least 1, got {self.num_demos}")
        if self.n_obs_steps != 1:
            raise ValueError(f"demo_replay reads the current observation only: n_obs_steps must be 1, got {self.n_obs_steps}")
        self.registration_config()

    def registration_config(self) -> RegistrationConfig:
        """The ``RegistrationConfig`` these fields describe (validated)."""
        return RegistrationConfig(
            yaw_only=self.registration_yaw_only,
            overlap=self.registration_overlap,
            fine_points=self.registration_points,
        )

    def validate_features(self) -> None:
        """The policy reads ``observation.pointcloud (P, 3)`` and ``observation.state (8,)`` and writes ``action (8,)``."""
        inputs = self.input_features or {}
        outputs = self.output_features or {}
        problems = []
        cloud = inputs.get(POINTCLOUD_KEY)
        if cloud is None or len(cloud.shape) != 2 or cloud.shape[1] != 3:
            problems.append(f"input {POINTCLOUD_KEY!r} of shape (P, 3), got {cloud.shape if cloud else 'nothing'}")
        state = inputs.get(STATE_KEY)
        if state is None or tuple(state.shape) != (8,):
            problems.append(f"input {STATE_KEY!r} of shape (8,), got {state.shape if state else 'nothing'}")
        action = outputs.get(ACTION_KEY)
        if action is None or tuple(action.shape) != (8,):
            problems.append(f"output {ACTION_KEY!r} of shape (8,), got {action.shape if action else 'nothing'}")
        if problems:
            raise ValueError("demo_replay needs " + "; ".join(problems))

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
