import lerobot_instant_policy  # noqa: F401
