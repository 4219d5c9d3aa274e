"""``MetaworldExpertPolicy``: MetaWorld's scripted expert of each task as a LeRobot policy (the upper bound).

Every step, for every batch row: the scripted policy of the row's ``task`` (LeRobot's ``TASK_POLICY_MAPPING``, the
``metaworld.policies`` class of the task) maps ``observation.environment_state (39,)`` to MetaWorld's action
``(4,)``, which :func:`~..sim.metaworld.actions.ee_target` turns into the contract's absolute EE target ``(8,)``
from ``observation.state (8,)``; the env maps that target back to the same 4-D action.
"""

import numpy as np
import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor

from ..contract import STATE_KEY
from ..data.demonstrations import batch_task_names
from ..sim.metaworld.expert import expert_target, scripted_policy
from .configuration_metaworld_expert import ENVIRONMENT_STATE_KEY, MetaworldExpertConfig
from .untrained import ParameterFreePolicyMixin


class MetaworldExpertPolicy(ParameterFreePolicyMixin, PreTrainedPolicy):
    """MetaWorld's scripted expert (see ``MetaworldExpertConfig``); no parameters, nothing to train."""

    config_class = MetaworldExpertConfig
    name = "metaworld_expert"

    def __init__(self, config: MetaworldExpertConfig, dataset_stats=None, dataset_meta=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        self.config: MetaworldExpertConfig = config
        self._experts: dict[str, object] = {}

    def reset(self) -> None:
        """Nothing to clear: MetaWorld's scripted policies are functions of the current state."""

    def get_optim_params(self) -> list:
        return []

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict | None]:
        raise RuntimeError("metaworld_expert has no trainable parameters: evaluate it with lerobot-eval")

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """A chunk of one action ``(B, 1, 8)``."""
        return self.select_action(batch)[:, None]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """Action ``(B, 8)`` float32: each row's expert action as an absolute EE target (module docstring)."""
        for key in (STATE_KEY, ENVIRONMENT_STATE_KEY):
            if key not in batch:
                raise KeyError(f"metaworld_expert needs {key!r} in the batch (--env.type=metaworld_pointcloud), got "
                               f"keys {sorted(batch)}")
        state = batch[STATE_KEY].detach().cpu().numpy()
        environment_state = batch[ENVIRONMENT_STATE_KEY].detach().cpu().numpy()
        tasks = batch_task_names(batch.get("task"), len(state), self.name, None, "; each a MetaWorld v3 task name such as "
                                 "'reach-v3'")
        targets = [expert_target(self.expert(task), row_state, row_ee, self.config.action_scale)
                   for task, row_state, row_ee in zip(tasks, environment_state, state, strict=True)]
        return torch.as_tensor(np.stack(targets), dtype=torch.float32, device=batch[STATE_KEY].device)

    def expert(self, task: str):
        """The scripted policy of ``task`` (a MetaWorld v3 task name), built once."""
        if task not in self._experts:
            self._experts[task] = scripted_policy(task)
        return self._experts[task]
