"""Measured speed on the user's machine of what they run, each benchmark a function that returns a JSON-ready dict
of figures.

``generation`` (pseudo-demonstration rendering, end-to-end generation and the shard merges), ``env``
(``bullet_tabletop`` steps), ``metaworld`` (LeRobot's MetaWorld env with clouds), ``policy`` (``instant_policy``
inference and training step, one setting at a time) and ``stream`` (training on the pseudo-task stream and the pool).
``lerobot-ip-bench`` is their command line. The repository's development benchmarks (the geometry encoder alone, a
training row's data, ``lerobot-train`` end to end, two settings compared in alternation) live in
``workbench/benchmarks``.
"""
