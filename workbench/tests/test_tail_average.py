"""Averaging saves' weights (``workbench.tail_average``): the mean of floating-point tensors, integer buffers from
the last save, a folder LeRobot loads as the shipped checkpoint's twin, mismatched saves refused and nothing half
written."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from safetensors.torch import load_file, save_file

from workbench.standing import SHIPPED
from workbench.tail_average import WEIGHTS, AverageError, average_weights, write_average


def _model(folder, scale: float, step: int, extra: str | None = None):
    folder.mkdir(parents=True)
    tensors = {"layer.weight": torch.full((2, 3), scale), "layer.bias": torch.arange(3.0) * scale,
               "counter": torch.tensor([step])}
    if extra:
        tensors[extra] = torch.zeros(1)
    save_file(tensors, str(folder / WEIGHTS))
    (folder / "config.json").write_text(json.dumps({"step": step}))
    return folder


def test_the_average_is_the_mean_of_the_weights_with_the_last_saves_buffers_and_config(tmp_path):
    models = [_model(tmp_path / f"m{k}", scale, step) for k, (scale, step) in enumerate([(1.0, 5), (2.0, 6), (6.0, 7)])]
    out = write_average(models, tmp_path / "mean")
    tensors = load_file(out / WEIGHTS)
    assert torch.equal(tensors["layer.weight"], torch.full((2, 3), 3.0))
    assert torch.allclose(tensors["layer.bias"], torch.arange(3.0) * 3.0)
    assert tensors["layer.weight"].dtype == torch.float32 and tensors["counter"].tolist() == [7]
    assert json.loads((out / "config.json").read_text()) == {"step": 7}  # the last save's config and processors
    assert not (tmp_path / "mean.building").exists()


def test_saves_that_do_not_match_are_refused_and_nothing_is_written(tmp_path):
    first = _model(tmp_path / "a", 1.0, 1)
    with pytest.raises(AverageError, match="other tensors"):
        write_average([first, _model(tmp_path / "b", 1.0, 2, extra="new.weight")], tmp_path / "mean")
    shaped = _model(tmp_path / "c", 1.0, 3)
    save_file({**load_file(shaped / WEIGHTS), "layer.weight": torch.zeros(3, 2)}, str(shaped / WEIGHTS))
    with pytest.raises(AverageError, match=r"layer.weight is \(3, 2\)"):
        average_weights([first, shaped])
    assert not (tmp_path / "mean").exists() and not (tmp_path / "mean.building").exists()
    with pytest.raises(AverageError, match="at least one"):
        average_weights([])
    with pytest.raises(FileExistsError, match="choose a new folder"):
        write_average([first], first)


def test_the_average_of_a_checkpoint_with_itself_loads_and_acts_as_it(tmp_path):
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    copy = tmp_path / "copy"
    shutil.copytree(SHIPPED, copy)
    out = write_average([SHIPPED, copy], tmp_path / "mean")
    original, averaged = load_file(SHIPPED / WEIGHTS), load_file(out / WEIGHTS)
    assert original.keys() == averaged.keys()
    assert all(torch.equal(original[key], averaged[key]) for key in original)
    policy = InstantPolicyPolicy.from_pretrained(out)  # LeRobot's loader reads it as it reads a save
    assert all(torch.equal(value, original[key]) for key, value in policy.state_dict().items() if key in original)


def test_the_command_line_averages_saves_and_refuses_an_existing_folder(tmp_path, capsys):
    from workbench.cli.standing import main

    saves = []
    for k in range(2):  # saves as a run leaves them: the pretrained_model folder inside
        saves.append(tmp_path / f"save{k}")
        _model(saves[-1] / "pretrained_model", float(k), k)
    assert main(["average", *map(str, saves), "--out", str(tmp_path / "mean")]) == 0
    assert json.loads(capsys.readouterr().out)["averaged"] == [str(save / "pretrained_model") for save in saves]
    assert torch.equal(load_file(tmp_path / "mean" / WEIGHTS)["layer.weight"], torch.full((2, 3), 0.5))
    assert main(["average", *map(str, saves), "--out", str(tmp_path / "mean")]) == 2
    assert "exists" in capsys.readouterr().err
