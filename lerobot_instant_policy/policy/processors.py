"""The pre/post-processors of every policy of this package: LeRobot's default steps, and one step of ours that gives an
unbatched point cloud its batch dimension.

LeRobot's ``to_batch_processor`` adds the batch dimension to ``observation.state (D,)`` and to images, which it knows
by key, but not to ``observation.pointcloud (P, 3)``, so one observation sent through the default preprocessor
reached ``select_action`` with a cloud of shape ``(P, 3)`` beside a state of shape ``(1, 8)``.
:class:`AddPointCloudBatchDimensionStep` follows it: a cloud ``(P, 3)`` becomes ``(1, P, 3)``, a batched one
``(B, P, 3)`` passes unchanged (``lerobot-eval``'s vectorised envs send batches).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature, PreTrainedConfig
from lerobot.processor import (
    ObservationProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    ProcessorStepRegistry,
    make_default_policy_processor_steps,
    make_policy_processor_pipelines,
)
from torch import Tensor

from ..contract import POINTCLOUD_KEY

POINTCLOUD_TO_BATCH = "ip_pointcloud_to_batch"


@dataclass
@ProcessorStepRegistry.register(name=POINTCLOUD_TO_BATCH)
class AddPointCloudBatchDimensionStep(ObservationProcessorStep):
    """A tensor of shape ``(P, 3)`` under one of ``keys`` becomes ``(1, P, 3)``; any other shape, or a key the
    observation lacks, is left as it is."""

    keys: list[str] = field(default_factory=lambda: [POINTCLOUD_KEY])

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        for key in self.keys:
            value = observation.get(key)
            if isinstance(value, Tensor) and value.dim() == 2:
                observation[key] = value.unsqueeze(0)
        return observation

    def get_config(self) -> dict[str, Any]:
        return {"keys": list(self.keys)}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        """Features describe one sample, without the batch dimension: unchanged."""
        return features


def make_point_cloud_policy_processors(
    config: PreTrainedConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """Pre-processor: rename observations → add a batch dimension (LeRobot's step, then
    :class:`AddPointCloudBatchDimensionStep`) → move to ``config.device`` → normalise. Post-processor: unnormalise →
    move to the CPU. LeRobot's steps keep their registered names (``rename_observations_processor``,
    ``device_processor``, …), which ``lerobot-eval`` overrides by name; the config's ``normalization_mapping``
    decides what the (un)normaliser does."""
    steps = make_default_policy_processor_steps(config, dataset_stats)
    return make_policy_processor_pipelines(
        input_steps=[steps.rename_observations, steps.add_batch_dim, AddPointCloudBatchDimensionStep(), steps.to_device,
                     steps.normalize],
        output_steps=[steps.unnormalize, steps.to_cpu],
    )
