"""Pre/post-processors of ``demo_replay``: LeRobot's default steps (rename, batch, device, identity normalisation),
and an unbatched point cloud given its batch dimension (:mod:`..policy.processors`)."""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline

from ..policy.processors import make_point_cloud_policy_processors
from .configuration_demo_replay import DemoReplayConfig


def make_demo_replay_pre_post_processors(
    config: DemoReplayConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """LeRobot's default pipelines with the point-cloud batch step; the config's ``normalization_mapping`` is
    IDENTITY, so values pass unchanged (point clouds and poses stay in metres, world frame)."""
    return make_point_cloud_policy_processors(config, dataset_stats)
