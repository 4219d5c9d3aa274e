"""Command-line entry points (``lerobot-ip-*``)."""
