"""Pre/post-processors of ``instant_policy``: LeRobot's default steps with IDENTITY normalisation (docs/design.md §3),
and an unbatched point cloud given its batch dimension as LeRobot's batch step gives the state its own
(:mod:`.policy.processors`).

All normalisation happens inside the model (relative SE(3) actions in a normalised tangent space), so the point
cloud, the EE state and the actions pass LeRobot's normaliser unchanged, in metres and the world frame. The steps
keep LeRobot's default names (``rename_observations_processor``, ``device_processor``, …), which ``lerobot-eval``
overrides by name.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import PolicyAction, PolicyProcessorPipeline

from .configuration_instant_policy import InstantPolicyConfig
from .policy.processors import make_point_cloud_policy_processors


def make_instant_policy_pre_post_processors(
    config: InstantPolicyConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """Pre-processor: rename observations → add a batch dimension (the state's, then an unbatched ``(P, 3)`` point
    cloud's) → move to ``config.device`` → normalise (IDENTITY). Post-processor: unnormalise (IDENTITY) → move to the
    CPU."""
    return make_point_cloud_policy_processors(config, dataset_stats)
