"""Classical baselines registered as LeRobot policies: ``demo_replay`` (registration + demonstration replay)."""

from .configuration_demo_replay import DemoReplayConfig

__all__ = ["DemoReplayConfig"]
