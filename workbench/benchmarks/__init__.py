"""Benchmarks that only this repository's development weighs, each a function that returns a JSON-ready dict of
figures: ``encoder`` (geometry encoder and farthest-point sampling, both presets, random weights), ``data`` (a
training row's action chunk: LeRobot's delta timestamps against the policy's action table), ``splat`` (the stream's
splatting settings against pybullet), ``lerobot_train`` (``lerobot-train`` itself end to end, per loader workers and
OpenMP wait policy) and ``variants`` (one setting of the installed inference or training-step benchmark on and off in
alternation, and their ratio). ``python -m workbench.cli.bench`` is their command line; the user-facing ones stay in
the package (``lerobot-ip-bench``, :mod:`lerobot_instant_policy.benchmarks`)."""
