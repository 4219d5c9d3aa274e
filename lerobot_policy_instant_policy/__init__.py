"""LeRobot plugin discovery entry point: LeRobot imports this module because the distribution is named
``lerobot_policy_instant_policy``; it imports the real package, which registers what it provides."""

import lerobot_instant_policy  # noqa: F401
