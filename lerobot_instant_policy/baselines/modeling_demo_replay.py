"""``DemoReplayPolicy``: the classical baseline: replay a registered demonstration.

At the first ``select_action`` after ``reset()``, for every batch element: load (once per task) the
demonstrations of its task and plan the replay of the one that fits the current cloud best
(:func:`~..replay.plan.plan_replay`). Call ``k`` returns planned action ``k``, the plan read by control step as
``instant_policy`` reads its replay (:func:`~..replay.priors.replay_priors`); after the last one the last action is
repeated.
"""

import logging

import numpy as np
import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor

from ..contract import POINTCLOUD_KEY, STATE_KEY
from ..data.demonstrations import Demonstration, DemonstrationSource
from ..replay.plan import ReplayPlan, plan_replay
from ..replay.priors import replay_priors
from .configuration_demo_replay import DemoReplayConfig
from .untrained import ParameterFreePolicyMixin

logger = logging.getLogger(__name__)


class DemoReplayPolicy(ParameterFreePolicyMixin, PreTrainedPolicy):
    """Registration + replay of a demonstration; no trainable parameters (see ``DemoReplayConfig``)."""

    config_class = DemoReplayConfig
    name = "demo_replay"

    def __init__(self, config: DemoReplayConfig, dataset_stats=None, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config: DemoReplayConfig = config
        self._plans: list[ReplayPlan] | None = None
        self._step = 0
        self._demonstrations = DemonstrationSource("demo_replay", config.demo_repo_id, config.demo_root, config.num_demos)

    def set_demonstrations(self, demonstrations: list[Demonstration]) -> None:
        """Use ``demonstrations`` (all of one task) for that task instead of reading ``demo_root``."""
        self._demonstrations.hand_in(demonstrations)
        self.reset()

    def demonstrations(self, task: str) -> list[Demonstration]:
        """The demonstrations of ``task``: handed in, or read from the configured dataset on first use."""
        return self._demonstrations.get(task)

    @property
    def plans(self) -> list[ReplayPlan] | None:
        """The current episode's plan per batch element (``None`` before the first ``select_action``)."""
        return self._plans

    def reset(self) -> None:
        self._plans = None
        self._step = 0

    def get_optim_params(self) -> list:
        return []

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict | None]:
        raise RuntimeError("demo_replay has no trainable parameters: evaluate it with lerobot-eval, do not train it")

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """The remaining planned actions ``(B, S, 8)`` from the current step (the last action repeated to align)."""
        self._ensure_plans(batch)
        remaining = max(1, max(len(plan.actions) for plan in self._plans) - self._step)
        return torch.from_numpy(self._actions_from(remaining)).to(batch[STATE_KEY].device)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Action ``(B, 8)`` for the current step: the plan's action at this step (absolute EE pose + gripper)."""
        self._ensure_plans(batch)
        action = self._actions_from(1)[:, 0]
        self._step += 1
        return torch.from_numpy(action).to(batch[STATE_KEY].device)

    def _actions_from(self, count: int) -> np.ndarray:
        """``(B, count, 8)``: each plan's actions from the current step on."""
        step = np.array([self._step])
        return np.concatenate([replay_priors(plan, step, count) for plan in self._plans])

    def _ensure_plans(self, batch: dict[str, Tensor]) -> None:
        if self._plans is not None:
            if len(self._plans) != len(batch[STATE_KEY]):
                raise ValueError(
                    f"batch size changed from {len(self._plans)} to {len(batch[STATE_KEY])} within an episode; "
                    "call reset() between episodes"
                )
            return
        if POINTCLOUD_KEY not in batch:
            raise KeyError(f"demo_replay needs {POINTCLOUD_KEY!r} in the batch, got keys {sorted(batch)}")
        clouds = batch[POINTCLOUD_KEY].detach().cpu().numpy()
        tasks = self._batch_tasks(batch, len(clouds))
        self._plans = [self._plan(task, cloud) for task, cloud in zip(tasks, clouds, strict=True)]
        for index, plan in enumerate(self._plans):
            logger.info(
                "demo_replay env %d: task %r, demonstration %d, fit error %.4f m, inliers %.2f",
                index, plan.task, plan.demo_index, plan.registration.fit_error, plan.registration.inlier_ratio,
            )

    def _batch_tasks(self, batch: dict, batch_size: int) -> list[str]:
        """Each row's task: ``batch["task"]``, or without it the one task of the demonstrations (handed in, or the
        demonstration dataset's); a ``KeyError`` that says what to pass where there are several."""
        return self._demonstrations.batch_tasks(batch.get("task"), batch_size)

    def _plan(self, task: str, cloud_now: np.ndarray) -> ReplayPlan:
        """Register every demonstration of ``task`` onto ``cloud_now (P, 3)``; plan the best one's actions."""
        return plan_replay(task, self.demonstrations(task), cloud_now, self.config.registration_config(),
                           self.config.replay_plan())
