"""MetaWorld's scripted experts (``metaworld.policies``, one per task, as LeRobot maps them in
``TASK_POLICY_MAPPING``) acting through the data contract: the demonstrator of ``lerobot-ip-record-demos --env
metaworld`` and the ``metaworld_expert`` policy."""

from __future__ import annotations

import numpy as np

from .actions import ee_target


def scripted_policy(task: str):
    """A new instance of the scripted policy of MetaWorld v3 task ``task``; ``ValueError`` for an unknown task."""
    from .dependencies import import_metaworld

    import_metaworld()
    from lerobot.envs.metaworld import TASK_POLICY_MAPPING

    if task not in TASK_POLICY_MAPPING:
        raise ValueError(f"no MetaWorld scripted policy for task {task!r}: give a MetaWorld v3 task name such as "
                         f"pick-place-v3")
    return TASK_POLICY_MAPPING[task]()


def expert_target(policy, environment_state: np.ndarray, state: np.ndarray, action_scale: float) -> np.ndarray:
    """The absolute EE target ``(8,)`` float32 of the scripted ``policy`` from MetaWorld's ``environment_state
    (39,)`` and the EE ``state (8,)`` (:func:`.actions.ee_target` of its 4-D action)."""
    return ee_target(policy.get_action(np.asarray(environment_state, dtype=np.float64)), state, action_scale)
