"""Training the policy beyond one ``lerobot-train`` call: ``rounds`` trains on pseudo-demonstrations generated while
training runs, round after round (``lerobot-ip-train-rounds``, ``make train-gpu``)."""
