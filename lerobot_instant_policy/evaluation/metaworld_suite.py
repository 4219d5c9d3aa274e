"""What the suite protocol (``evaluation.suite``) does differently in LeRobot's MetaWorld env
(``--env.type=metaworld_pointcloud``; ``lerobot-ip-eval-metaworld``, ``make eval-metaworld``).

* Demonstrations are MetaWorld's scripted expert's (``sim.metaworld.recording``), recorded through the data
  contract with the same step limit as the evaluation.
* Every ``lerobot-eval`` call sets ``--env.episode_length`` (default 200; MetaWorld's own limit is 500) and
  ``--env.pointcloud_every`` (default 8: the cloud is rendered on the steps ``instant_policy`` reads and after
  gripper changes; ``sim.metaworld.env``).
* ``metaworld_expert`` (the upper bound, reading MetaWorld's privileged state) is a policy of this env only.
* The context-swap control hands each task the demonstrations of a task of another kind: MT10's tasks that reach or
  move something to a place, that open, and that close or press (``SWAP_GROUPS``); a task outside MT10 is its own
  group. The sources are a permutation, every task's demonstrations read by one other task
  (``evaluation.suite.swap_sources``); docs/metaworld.md lists MT10's, beside the older pairing the committed MT10
  test-split swap ran with (door-open's demonstrations read twice, peg-insert-side's never).
"""

from __future__ import annotations

from pathlib import Path

ENV_TYPE = "metaworld_pointcloud"
POLICIES = ("instant_policy", "demo_replay", "do_nothing", "metaworld_expert")
DEFAULT_EPISODE_LENGTH = 200
DEFAULT_POINTCLOUD_EVERY = 8
SWAP_GROUPS = {
    "reach or move to a place": ("reach-v3", "push-v3", "pick-place-v3", "peg-insert-side-v3"),
    "open": ("door-open-v3", "drawer-open-v3", "window-open-v3"),
    "close or press": ("drawer-close-v3", "window-close-v3", "button-press-topdown-v3"),
}


def swap_group(task: str) -> str:
    """The MT10 kind of ``task`` for the swap control (module docstring); a task outside MT10 is its own group."""
    return next((group for group, tasks in SWAP_GROUPS.items() if task in tasks), task)


def record_demonstrations(settings, task: str, demos: Path, seed: int, source: str) -> None:
    """Record ``settings.num_demos`` expert demonstrations of ``source`` labelled ``task`` into ``demos``."""
    from ..sim.metaworld import recording

    recording.record_expert_demos(source, settings.num_demos, demos, f"local/{task}", seed, overwrite=True,
                                  label=task, episode_length=settings.episode_length)


def eval_flags(settings) -> list[str]:
    """The env flags of every ``lerobot-eval`` call in MetaWorld."""
    return [f"--env.episode_length={settings.episode_length}", f"--env.pointcloud_every={settings.pointcloud_every}"]


def conditions(settings, task: str, env_values: dict[str, str]) -> dict:
    """MetaWorld's part of a cell's conditions (``evaluation.suite.cell_conditions``): success is MetaWorld's own
    flag at a step (``hold_steps`` 1), the step limit is ``episode_length``, the video size ``--env.render_size`` or
    the env config's, and the cloud is rendered every ``pointcloud_every`` steps."""
    from ..sim.metaworld.configuration_metaworld import MetaworldPointCloudEnvConfig

    return {"success": "metaworld", "hold_steps": 1, "episode_length": settings.episode_length,
            "render_size": int(env_values.get("render_size", MetaworldPointCloudEnvConfig.render_size)),
            "obs_type": None, "pointcloud_every": settings.pointcloud_every}


def check(settings) -> str | None:
    """What is wrong with ``settings`` for MetaWorld (``None`` when nothing is)."""
    if not 0 < settings.episode_length <= 500:
        return f"episode_length must lie in 1…500 (MetaWorld's limit), got {settings.episode_length}"
    if settings.pointcloud_every < 1:
        return f"pointcloud_every must be at least 1, got {settings.pointcloud_every}"
    return None
