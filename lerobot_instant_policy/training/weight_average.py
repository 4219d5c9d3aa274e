"""An exponential moving average of the policy's trained weights, kept beside a training run (``lerobot-ip-train
--average.decay D``). After every optimizer step, over the trainable parameters only (the frozen encoder is the same
in both)::

    θ̄₀ = θ₀ (the weights the run starts or resumes with),     θ̄ₜ₊₁ = D · θ̄ₜ + (1 − D) · θₜ₊₁

(``torch.optim.swa_utils.get_ema_multi_avg_fn``), an average over a window of about 1 / (1 − D) steps. A run at a
near-constant learning rate leaves its weights wandering about a minimum at a distance the rate sets; their average
lies nearer it when that wandering, not the minimum's own progress, dominates the error.

It is saved with every LeRobot checkpoint, ``training_state/weight_average.safetensors`` (the parameters by their
names in the policy's state dict, the decay and the updates in its metadata), and read back on ``--resume=true``:
``pretrained_model/`` keeps the raw weights the run continues from, and the average goes on where it stopped (with
the saved decay unless ``--average.decay`` gives another).
:func:`write_averaged_model` turns a save into a ``pretrained_model`` folder holding the average, which every command
that reads a checkpoint loads.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file
from torch.optim.swa_utils import get_ema_multi_avg_fn

AVERAGE_FILE = "weight_average.safetensors"
WEIGHTS_FILE = "model.safetensors"


class WeightAverageError(ValueError):
    """A decay outside (0, 1), or a saved average that does not match the policy it is read into."""


class WeightAverage:
    """The moving average of ``policy``'s trainable parameters (module docstring), ``decay`` in (0, 1); it starts at
    their current values."""

    def __init__(self, policy: torch.nn.Module, decay: float):
        if not 0.0 < decay < 1.0:
            raise WeightAverageError(f"the average's decay must lie in (0, 1), got {decay}")
        self.decay = decay
        self.names = [name for name, parameter in policy.named_parameters() if parameter.requires_grad]
        parameters = dict(policy.named_parameters())
        self.average = [parameters[name].detach().clone() for name in self.names]
        self.updates = 0
        self._update = get_ema_multi_avg_fn(decay)

    def update(self, policy: torch.nn.Module) -> None:
        """One step of the average towards ``policy``'s current parameters (after an optimizer step)."""
        parameters = dict(policy.named_parameters())
        self._update(self.average, [parameters[name].detach() for name in self.names], self.updates)
        self.updates += 1

    def save(self, training_state: Path) -> Path:
        """Write the average into a checkpoint's ``training_state`` folder; returns the file."""
        path = Path(training_state) / AVERAGE_FILE
        tensors = {name: tensor.detach().cpu().contiguous() for name, tensor in zip(self.names, self.average)}
        save_file(tensors, str(path), metadata={"decay": repr(self.decay), "updates": str(self.updates)})
        return path

    @classmethod
    def resume(cls, policy: torch.nn.Module, decay: float, training_state: Path | None) -> "WeightAverage":
        """The average saved in ``training_state`` (a checkpoint's folder) read into one for ``policy``, going on
        with ``decay``; a fresh one (starting at ``policy``'s weights) where there is none (a run that did not
        average before). ``WeightAverageError`` when the saved parameters are not the policy's trainable ones."""
        average = cls(policy, decay)
        path = None if training_state is None else Path(training_state) / AVERAGE_FILE
        if path is None or not path.is_file():
            return average
        saved = load_file(path, device=str(average.average[0].device) if average.average else "cpu")
        if set(saved) != set(average.names):
            raise WeightAverageError(f"{path} averages other parameters than the policy trains: "
                                     f"{sorted(set(saved) ^ set(average.names))[:5]}")
        for index, name in enumerate(average.names):
            if saved[name].shape != average.average[index].shape:
                raise WeightAverageError(f"{name} is {tuple(saved[name].shape)} in {path}, "
                                         f"{tuple(average.average[index].shape)} in the policy")
            average.average[index] = saved[name].to(average.average[index].dtype)
        with safe_open(str(path), framework="pt") as handle:
            average.updates = int(handle.metadata()["updates"])
        return average


def saved_decay(training_state: Path | None) -> float | None:
    """The decay of the average saved in ``training_state`` (a checkpoint's folder), ``None`` where it holds none."""
    path = None if training_state is None else Path(training_state) / AVERAGE_FILE
    if path is None or not path.is_file():
        return None
    with safe_open(str(path), framework="pt") as handle:
        return float(handle.metadata()["decay"])


def write_averaged_model(save: Path, out: Path) -> Path:
    """The ``pretrained_model`` of ``save`` (a LeRobot step checkpoint with ``training_state/`` holding
    :data:`AVERAGE_FILE`) with its trained parameters replaced by their average, written to ``out`` (config and
    processors copied, :func:`write_model`). ``FileNotFoundError`` without an average, ``WeightAverageError`` when it
    names tensors the weights lack."""
    average_path = Path(save) / "training_state" / AVERAGE_FILE
    if not average_path.is_file():
        raise FileNotFoundError(f"{save} holds no weight average ({average_path}): it was trained without "
                                "--average.decay")
    weights = load_file(Path(save) / "pretrained_model" / WEIGHTS_FILE)
    average = load_file(average_path)
    unknown = sorted(set(average) - set(weights))
    if unknown:
        raise WeightAverageError(f"the average of {save} names tensors its weights lack: {unknown[:5]}")
    weights.update({name: tensor.to(weights[name].dtype) for name, tensor in average.items()})
    return write_model(Path(save) / "pretrained_model", weights, out)


def write_model(source: Path, weights: dict[str, torch.Tensor], out: Path) -> Path:
    """A ``pretrained_model`` folder at ``out`` holding ``weights`` (tensors by state-dict name) beside the config
    and processors of ``source`` (a pretrained_model folder). Built beside ``out`` and renamed into place, so a
    failure leaves no half folder; ``FileExistsError`` where ``out`` exists. Returns ``out``."""
    if out.exists():
        raise FileExistsError(f"{out} exists: choose a new folder")
    building = out.with_name(out.name + ".building")
    shutil.rmtree(building, ignore_errors=True)
    shutil.copytree(source, building, ignore=shutil.ignore_patterns(WEIGHTS_FILE))
    save_file(weights, str(building / WEIGHTS_FILE))
    building.rename(out)
    return out
