"""Baselines registered as LeRobot policies: ``demo_replay`` (registration + demonstration replay) and
``do_nothing`` (hold the current EE pose and gripper state: the lower bound), and ``metaworld_expert`` (MetaWorld's
scripted expert of each task: the upper bound of the MetaWorld table)."""

from .configuration_demo_replay import DemoReplayConfig
from .configuration_do_nothing import DoNothingConfig
from .configuration_metaworld_expert import MetaworldExpertConfig

__all__ = ["DemoReplayConfig", "DoNothingConfig", "MetaworldExpertConfig"]
