"""What the workbench's episode probes share: the replay executed by control step beside ``instant_policy`` run from
that replay's prior, on the same seeds (``workbench/scripts/plan_timing.py``, ``grasp_timing.py``,
``demo_end_margin.py``, ``lid_grasp.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.contract import POINTCLOUD_KEY, STATE_KEY
from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.replay.plan import ReplaySource
from lerobot_instant_policy.replay.priors import plan_onto_live
from lerobot_instant_policy.sim.env import BulletTabletopEnv


def seed_list(text: str) -> list[int]:
    """``"1000-1009"`` (both ends included) or ``"0,100,200"`` → the seeds (an ``argparse`` ``type=``)."""
    if "-" in text:
        first, last = (int(x) for x in text.split("-"))
        return list(range(first, last + 1))
    return [int(x) for x in text.split(",")]


def replay_policy(checkpoint: str | Path, plan: str, **fields) -> InstantPolicyPolicy:
    """The ``instant_policy`` checkpoint in eval mode on the CPU, its replay planned as ``plan`` (one of
    ``replay.plan.REPLAY_PLANS``: the config's three plan switches set to name it) and any further config
    ``fields`` set (``demo_root``, ``replay_init_strength`` …)."""
    config = InstantPolicyConfig.from_pretrained(checkpoint)
    config.replay_per_object, config.replay_anchored, config.replay_consensus = (
        plan == "per_object", plan == "anchored", plan == "consensus")
    config.device = "cpu"
    for name, value in fields.items():
        setattr(config, name, value)
    return InstantPolicyPolicy.from_pretrained(checkpoint, config=config).eval()


def start_episode(env: BulletTabletopEnv, task: str, demonstrations: list[Demonstration], plan: str, seed: int,
                  policy: InstantPolicyPolicy | None = None) -> tuple[dict, np.ndarray]:
    """Reset the suite's ``env`` to episode ``seed``: its first observation and the ``plan`` replay ``(G, 8)`` of
    ``demonstrations`` onto its first cloud, made as the policy makes it; ``policy``, if given, is handed the
    demonstrations (which starts its episode) and torch's generator seeded with ``seed``."""
    observation, _ = env.reset(seed=seed)
    planned = plan_onto_live(task, [ReplaySource.of(demo) for demo in demonstrations], observation["pointcloud"],
                             plan).actions
    if policy is not None:
        policy.set_demonstrations(demonstrations)
        torch.manual_seed(seed)
    return observation, planned


def episode_action(policy: InstantPolicyPolicy | None, plan: np.ndarray, step: int, observation: dict, task: str
                   ) -> np.ndarray:
    """The action ``(8,)`` at control ``step``: the replay's (``plan (G, 8)`` read by control step, its last action
    held past its end) where ``policy`` is None, else ``policy``'s for ``observation`` (the env's ``pointcloud``
    and ``agent_pos``) of ``task``."""
    if policy is None:
        return plan[min(step, len(plan) - 1)]
    batch = {POINTCLOUD_KEY: torch.from_numpy(observation["pointcloud"])[None].float(),
             STATE_KEY: torch.from_numpy(observation["agent_pos"])[None].float(), "task": [task]}
    return policy.select_action(batch)[0].numpy()
