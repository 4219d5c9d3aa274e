"""Baselines registered as LeRobot policies: ``demo_replay`` (registration + demonstration replay) and
``do_nothing`` (hold the current EE pose and gripper state: the lower bound)."""

from .configuration_demo_replay import DemoReplayConfig
from .configuration_do_nothing import DoNothingConfig

__all__ = ["DemoReplayConfig", "DoNothingConfig"]
