"""Runs of the ``lerobot-*`` commands as subprocesses: ``train_rounds`` trains on pseudo-demonstrations generated
while training runs, round after round (``lerobot-ip-train-rounds``, ``make campaign``, ``make train-gpu``)."""
