"""The LeRobot features every policy of this package reads and writes (the data contract, :mod:`.contract`).

Inputs ``observation.pointcloud (P, 3)`` (world frame) and ``observation.state (8,)``; output ``action (8,)``.
All normalisation is IDENTITY in LeRobot's processors: the policies normalise inside the model.
"""

from __future__ import annotations

from lerobot.configs import FeatureType, NormalizationMode, PolicyFeature

from ..contract import ACTION_KEY, NUM_POINTS, POINTCLOUD_KEY, POSE_GRIPPER_SHAPE, STATE_KEY


def contract_input_features(num_points: int = NUM_POINTS) -> dict[str, PolicyFeature]:
    """The inputs of the data contract, with clouds of ``num_points`` points."""
    return {
        POINTCLOUD_KEY: PolicyFeature(type=FeatureType.STATE, shape=(num_points, 3)),
        STATE_KEY: PolicyFeature(type=FeatureType.STATE, shape=POSE_GRIPPER_SHAPE),
    }


def contract_output_features() -> dict[str, PolicyFeature]:
    return {ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=POSE_GRIPPER_SHAPE)}


def identity_normalization() -> dict[str, NormalizationMode]:
    return {
        "VISUAL": NormalizationMode.IDENTITY,
        "STATE": NormalizationMode.IDENTITY,
        "ENV": NormalizationMode.IDENTITY,
        "ACTION": NormalizationMode.IDENTITY,
    }


def check_policy_features(
    policy_name: str, input_features: dict[str, PolicyFeature] | None, output_features: dict[str, PolicyFeature] | None
) -> None:
    """Raise ``ValueError`` naming every input or output feature of the policy ``policy_name`` that is missing or of
    the wrong shape."""
    inputs = input_features or {}
    outputs = output_features or {}
    problems = []
    cloud = inputs.get(POINTCLOUD_KEY)
    if cloud is None or len(cloud.shape) != 2 or cloud.shape[1] != 3 or cloud.shape[0] < 1:
        problems.append(f"input {POINTCLOUD_KEY!r} of shape (P, 3), got {cloud.shape if cloud else 'nothing'}")
    state = inputs.get(STATE_KEY)
    if state is None or tuple(state.shape) != POSE_GRIPPER_SHAPE:
        problems.append(f"input {STATE_KEY!r} of shape (8,), got {state.shape if state else 'nothing'}")
    action = outputs.get(ACTION_KEY)
    if action is None or tuple(action.shape) != POSE_GRIPPER_SHAPE:
        problems.append(f"output {ACTION_KEY!r} of shape (8,), got {action.shape if action else 'nothing'}")
    if problems:
        raise ValueError(f"{policy_name} needs " + "; ".join(problems))
