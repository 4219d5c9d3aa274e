"""Measured speed of the project's parts, each benchmark a function that returns a JSON-ready dict of figures.

``generation`` (pseudo-demonstration rendering, end-to-end generation and the shard merges), ``encoder`` (geometry
encoder and farthest-point sampling), ``env`` (``bullet_tabletop`` steps), ``data`` (a training row's action chunk),
``policy`` (``instant_policy`` inference and training step), ``lerobot_train`` (``lerobot-train`` itself, end to end)
and ``variants`` (one setting on and off in alternation, and their ratio). ``lerobot-ip-bench`` is their command line.
"""
