"""Reading out what a run's weights know by averaging them: the mean of several saves' weights, written as a LeRobot
``pretrained_model`` that any command loads (``lerobot-ip-action-error``, ``lerobot-eval``, ``standing compare``).

A run at a near-constant learning rate leaves its weights wandering about a minimum at a distance the rate sets; the
mean of its saves over a window (a tail average, as stochastic weight averaging takes) lies nearer the minimum than
any one of them when that wandering, not the minimum's own progress, dominates the error. The saves are LeRobot step
checkpoints ``save_freq`` steps apart, so a tail of k saves averages a window of about k × ``save_freq`` steps: the
window an exponential moving average with decay ``1 − 1 / window`` would hold (the average a run keeps while it
trains, :mod:`lerobot_instant_policy.training.weight_average`). Comparing tails of several lengths, paired against the
last save on the validation sets, measures which window (hence which decay) reads out the most.

``python -m workbench.cli.standing average SAVE [SAVE ...] --out DIR``.
"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors.torch import load_file

from lerobot_instant_policy.training.weight_average import WEIGHTS_FILE as WEIGHTS
from lerobot_instant_policy.training.weight_average import write_model


class AverageError(ValueError):
    """Saves that cannot be averaged (none, other tensors, other shapes), with what differs."""


def average_weights(models: list[Path]) -> dict[str, torch.Tensor]:
    """The mean over ``models`` (pretrained_model folders) of every floating-point tensor of their
    ``model.safetensors``, accumulated in float64 and stored in each tensor's own dtype; other tensors (integer
    buffers) are the last model's. ``AverageError`` when the models hold other keys, shapes or dtypes."""
    if not models:
        raise AverageError("averaging needs at least one save")
    first = load_file(models[0] / WEIGHTS)
    sums = {key: tensor.double() if tensor.is_floating_point() else tensor for key, tensor in first.items()}
    for model in models[1:]:
        tensors = load_file(model / WEIGHTS)
        if tensors.keys() != first.keys():
            raise AverageError(f"{model} holds other tensors than {models[0]}: "
                               f"{sorted(tensors.keys() ^ first.keys())[:5]}")
        for key, tensor in tensors.items():
            if tensor.shape != first[key].shape or tensor.dtype != first[key].dtype:
                raise AverageError(f"{key} is {tuple(tensor.shape)} {tensor.dtype} in {model}, "
                                   f"{tuple(first[key].shape)} {first[key].dtype} in {models[0]}")
            sums[key] = sums[key] + tensor.double() if tensor.is_floating_point() else tensor
    return {key: (value / len(models)).to(first[key].dtype) if first[key].is_floating_point() else value
            for key, value in sums.items()}


def write_average(models: list[Path], out: Path) -> Path:
    """:func:`average_weights` of ``models`` written to ``out`` as a pretrained_model folder beside the last model's
    config and processors (:func:`~lerobot_instant_policy.training.weight_average.write_model`: ``FileExistsError``
    where ``out`` exists, no half folder on a failure). Returns ``out``."""
    if out.exists():
        raise FileExistsError(f"{out} exists: choose a new folder")
    return write_model(models[-1], average_weights(models), out)
