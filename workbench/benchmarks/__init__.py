"""Benchmarks of the package's internals that only this repository's development weighs, each a function that
returns a JSON-ready dict of figures: ``encoder`` (geometry encoder and farthest-point sampling, both presets, random
weights) and ``data`` (a training row's action chunk: LeRobot's delta timestamps against the policy's action table).
``python -m workbench.cli.bench`` is their command line; the user-facing ones stay in the package
(``lerobot-ip-bench``, :mod:`lerobot_instant_policy.benchmarks`)."""
