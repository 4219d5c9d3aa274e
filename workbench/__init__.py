"""Research tooling of this repository, not installed with the package: run it from the repository root as
``python -m workbench.<module>`` (the working directory puts this folder on the import path).

``train_rounds`` trains on pseudo-demonstrations generated while training runs, round after round (``make
train-gpu``, ``make campaign``), by starting the installed commands (``lerobot-ip-generate``, ``lerobot-train``,
``lerobot-ip-action-error``, ``lerobot-ip-loss-curve``) as subprocesses; ``standing`` is the standing training run;
``action_error_sweep`` measures the action error as K, N and L vary (the paper's table 2, right half), at every
setting the installed probe's; ``benchmarks`` times parts whose speed only this repository's development weighs and
compares two settings of the installed benchmarks (``python -m workbench.cli.bench``); ``cli`` holds their command
lines and ``tests`` their tests (collected by ``make test``). ``configs/generate`` holds the pseudo-task ladder's
generation presets (``make ladder``) and ``scripts`` one-off research scripts (``python workbench/scripts/<name>.py``).
It imports the installed package, which never imports it.
"""
