"""``python -m workbench.cli.action_error_sweep``: the installed action-error probe at every setting of a K, N, L
grid (one parameter varied at a time around the default), on the same frames and noise, with the references at the
default setting."""

from __future__ import annotations

import json
import math

import pytest
import torch

from lerobot_instant_policy.cli.generate import main as generate_main
from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from lerobot_instant_policy.evaluation import action_error as ae
from workbench.action_error_sweep import action_error_sweep, grid
from workbench.cli.action_error_sweep import main

SHIPPED = SHIPPED_CHECKPOINT


@pytest.fixture(scope="module", autouse=True)
def single_torch_thread():
    """One intra-op torch thread: the small model runs several times faster on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def held_out_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("action_error_sweep") / "val"
    assert generate_main(["--out", str(root), "--repo-id", "local/val", "--num-tasks", "2", "--demos-per-task", "3",
                          "--seed", "3", "--object-split", "held_out", "--workers", "1", "--no-progress"]) == 0
    return root


def _sweep(root, **overrides):
    settings = dict(tasks=2, frames_per_task=1, seed=0, ks=[1, 4], ns=[2], ls=[10], untrained=False)
    return action_error_sweep(SHIPPED, root, **{**settings, **overrides})


def test_the_grid_varies_one_parameter_at_a_time_around_the_default():
    assert grid([1, 4], [1, 2], [5, 10], (4, 2, 10)) == [(4, 2, 10), (1, 2, 10), (4, 1, 10), (4, 2, 5)]


def test_every_setting_is_the_probes_on_the_same_frames_and_noise(held_out_root, monkeypatch):
    from lerobot_instant_policy.model.instant_policy_network import InstantPolicyNetwork

    denoise, calls = InstantPolicyNetwork.denoise, []
    monkeypatch.setattr(InstantPolicyNetwork, "denoise", lambda self, *a, **k: calls.append(1) or denoise(self, *a, **k))
    swept = _sweep(held_out_root)
    # K = 4 and K = 1 on 2 frames, then the K = 4 swap on 2 frames: each prediction denoised exactly K times
    assert len(calls) == 2 * 4 + 2 * 1 + 2 * 4
    assert [(row["K"], row["N"], row["L"]) for row in swept["settings"]] == [(4, 2, 10), (1, 2, 10)]
    assert swept["default"] == {"K": 4, "N": 2, "L": 10} and swept["frames"] == 2
    rows = {row["K"]: row for row in swept["settings"]}
    assert (rows[1]["translation_mm"], rows[1]["rotation_deg"]) != (rows[4]["translation_mm"], rows[4]["rotation_deg"])
    assert swept["context_gain"]["translation"] == round(swept["swap"]["translation_mm"] / rows[4]["translation_mm"], 3)
    assert set(swept["phases"]) == set(ae.THIRDS)
    # the default row, the swap and holding still are the installed probe's at that setting
    probe = ae.action_error(SHIPPED, held_out_root, tasks=2, frames_per_task=1, seed=0, untrained=False)
    for key in ("swap", "hold", "context_gain", "phases"):
        strip = {name: value for name, value in swept[key].items() if name != "ms_per_prediction"}
        assert strip == {name: value for name, value in probe[key].items() if name != "ms_per_prediction"}, key
    assert swept["per_task"] == probe["per_task"] and swept["intervals"] == probe["intervals"]
    assert ({name: value for name, value in rows[4].items() if name != "ms_per_prediction"}
            == {name: value for name, value in probe["settings"][0].items() if name != "ms_per_prediction"})


def test_a_value_outside_the_configs_ranges_is_refused_before_anything_runs(held_out_root, monkeypatch):
    monkeypatch.setattr(ae, "load_policy", lambda *args, **kwargs: pytest.fail("the weights were loaded"))
    with pytest.raises(ae.ActionErrorError, match=r"num_waypoints \(L\) must be an integer in the supported range"):
        _sweep(held_out_root, ls=[10, 40])
    with pytest.raises(ae.ActionErrorError, match=r"inference_steps \(K\)"):
        _sweep(held_out_root, default=(0, 2, 10))


def test_the_command_line_prints_every_row_and_refuses_bad_input(held_out_root, capsys):
    assert main(["--policy-path", str(SHIPPED), "--root", str(held_out_root), "--tasks", "2", "--frames-per-task",
                 "1", "--K", "1", "--N", "1,2", "--L", "10", "--default", "1,2,10", "--no-untrained", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [(row["K"], row["N"], row["L"]) for row in result["settings"]] == [(1, 2, 10), (1, 1, 10)]
    assert all(math.isfinite(row["translation_mm"]) for row in result["settings"])
    assert main(["--policy-path", str(SHIPPED), "--root", str(held_out_root), "--tasks", "2", "--N", "3"]) == 2
    assert "N can be at most 2" in capsys.readouterr().err
    assert main(["--policy-path", str(SHIPPED), "--root", str(held_out_root), "--default", "4,2"]) == 2
    assert "--default takes K,N,L" in capsys.readouterr().err
