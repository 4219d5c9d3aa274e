"""Research tooling of this repository, not installed with the package: run it from the repository root as
``python -m workbench.<module>`` (the working directory puts this folder on the import path).

``train_rounds`` trains on pseudo-demonstrations generated while training runs, round after round (``make
train-gpu``, ``make campaign``), by starting the installed commands (``lerobot-ip-generate``, ``lerobot-train``,
``lerobot-ip-action-error``, ``lerobot-ip-loss-curve``) as subprocesses; ``benchmarks`` times parts whose speed only
this repository's development weighs (``python -m workbench.cli.bench``); ``cli`` holds their command lines and
``tests`` their tests (collected by ``make test``). It imports the installed package, which never imports it.
"""
