"""Research tooling of this repository, not installed with the package: run it from the repository root as
``python -m workbench.<module>`` (the working directory puts this folder on the import path).

``standing`` is the standing training run, which starts the installed commands (``lerobot-ip-train``,
``lerobot-ip-generate``, ``lerobot-ip-action-error``) as subprocesses; ``action_error_sweep`` measures the action
error as K, N and L vary (the paper's table 2, right half), at every setting the installed probe's; ``benchmarks``
times parts whose speed only this repository's development weighs and compares two settings of the installed
benchmarks (``python -m workbench.cli.bench``); ``cli`` holds their command lines and ``tests`` their tests
(collected by ``make test``). ``configs/generate`` holds generation presets of the pseudo-task families' rungs (the
fixed sets the checkpoint shipped before was trained on, earlier held-out sets, the in-context learning test's) and
``scripts`` one-off research scripts (``python workbench/scripts/<name>.py``).
It imports the installed package, which never imports it.
"""
