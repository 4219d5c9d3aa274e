"""The moving average of the trained weights (``training.weight_average``): the exact recursion over the trainable
parameters only, a save read back as it was, a saved average that does not fit refused, and bad decays refused."""

from __future__ import annotations

import pytest
import torch

from lerobot_instant_policy.training.weight_average import AVERAGE_FILE, WeightAverage, WeightAverageError


def _module() -> torch.nn.Module:
    module = torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.Linear(2, 1))
    module[1].weight.requires_grad_(False)  # frozen, as the geometry encoder is
    return module


def _step(module: torch.nn.Module, value: float) -> None:
    with torch.no_grad():
        for parameter in module.parameters():
            parameter.fill_(value)


def test_the_average_follows_its_recursion_over_the_trained_parameters_only():
    module = _module()
    _step(module, 1.0)
    average = WeightAverage(module, decay=0.9)
    assert "1.weight" not in average.names and {"0.weight", "0.bias", "1.bias"} == set(average.names)
    expected = 1.0
    for value in (2.0, 5.0, -1.0):
        _step(module, value)
        average.update(module)
        expected = 0.9 * expected + 0.1 * value
    for tensor in average.average:
        assert torch.allclose(tensor, torch.full_like(tensor, expected))
    assert average.updates == 3 and module[0].weight.eq(-1.0).all()  # the module's own weights are left as they are


def test_a_saved_average_is_read_back_and_goes_on_and_one_that_does_not_fit_is_refused(tmp_path):
    module = _module()
    average = WeightAverage(module, decay=0.5)
    _step(module, 4.0)
    average.update(module)
    assert average.save(tmp_path).name == AVERAGE_FILE
    resumed = WeightAverage.resume(_module(), 0.5, tmp_path)  # a fresh module: the saved average, not its weights
    assert resumed.updates == 1 and resumed.names == average.names
    assert all(torch.equal(a, b) for a, b in zip(resumed.average, average.average))
    fresh = WeightAverage.resume(module, 0.5, tmp_path / "nothing")  # a run that did not average before
    assert fresh.updates == 0 and all(t.eq(4.0).all() for t in fresh.average)
    wider = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 1))
    wider[1].weight.requires_grad_(False)
    with pytest.raises(WeightAverageError, match=r"0.weight is \(2, 3\)"):
        WeightAverage.resume(wider, 0.5, tmp_path)
    with pytest.raises(WeightAverageError, match="other parameters"):
        WeightAverage.resume(torch.nn.Linear(3, 2), 0.5, tmp_path)


@pytest.mark.parametrize("decay", [0.0, 1.0, -0.1, 1.5])
def test_a_decay_outside_the_open_interval_is_refused(decay):
    with pytest.raises(WeightAverageError, match=r"lie in \(0, 1\)"):
        WeightAverage(_module(), decay)
