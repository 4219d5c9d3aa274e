"""The stream lease (``workbench.stream_lease``): which checkpoint a lease continues, when its weights are kept, the
point it adds to the scaling curve, bad settings; and, slow, one whole lease on the CPU under a short deadline."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from workbench.stream_lease import SHIPPED, LeaseConfig, accept, accepted_leases, beats, start_checkpoint


def _lease(moved: float, one_layout: float, start: tuple[float, float] = (0.9, 0.6), samples: int = 100) -> dict:
    def result(value, start_value):
        return {"checkpoint": {"translation_mm": 30 * value, "hold_translation_mm": 30.0, "vs_holding_still": value,
                               "context_gain": 1.3},
                "start": {"translation_mm": 30 * start_value, "hold_translation_mm": 30.0,
                          "vs_holding_still": start_value, "context_gain": 1.3}}

    return {"samples_total": samples, "tasks_total": samples, "hidden_dim": 128, "device": "cpu", "start": "shipped",
            "seed": 1000,
            "config": {"val_tasks": 24, "val_frames_per_task": 4},
            "validation": {"moved": result(moved, start[0]), "one_layout": result(one_layout, start[1])}}


def _folder(tmp_path: Path, name: str, lease: dict) -> Path:
    folder = tmp_path / name
    folder.mkdir()
    (folder / "lease.json").write_text(json.dumps(lease))
    (folder / "model.safetensors").write_bytes(b"weights")
    return folder


def test_a_lease_is_kept_only_when_it_beats_the_last_kept_one_on_both_sets_and_every_lease_is_a_curve_point(tmp_path):
    committed, curve = tmp_path / "checkpoints", tmp_path / "curve.json"
    worse = accept(_folder(tmp_path, "a", _lease(0.95, 0.5)), committed=committed, curve_file=curve)
    assert not worse["kept"] and not committed.exists()  # moved objects: 0.95 against its start's 0.9
    first = accept(_folder(tmp_path, "b", _lease(0.85, 0.55, samples=200)), committed=committed, curve_file=curve)
    assert first["kept"] and (committed / "lease_000" / "model.safetensors").read_bytes() == b"weights"
    assert start_checkpoint(LeaseConfig(), committed) == committed / "lease_000"
    second = accept(_folder(tmp_path, "c", _lease(0.84, 0.56, samples=300)), committed=committed, curve_file=curve)
    assert not second["kept"]  # one layout: 0.56 against the kept 0.55
    points = json.loads(curve.read_text())["points"]
    assert [point["samples_total"] for point in points] == [100, 200, 300]
    assert [point["kept"] for point in points] == [False, True, False]
    assert points[1]["moved_vs_holding_still"] == 0.85 and points[1]["val_tasks"] == 24
    assert len(accepted_leases(committed)) == 1
    assert curve.with_suffix(".png").stat().st_size > 10_000  # the picture is redrawn beside the JSON


def test_a_lease_starts_from_the_shipped_checkpoint_or_the_one_asked_for(tmp_path):
    assert start_checkpoint(LeaseConfig(), tmp_path / "none") == SHIPPED
    assert start_checkpoint(LeaseConfig(start="some/pretrained_model"), tmp_path) == Path("some/pretrained_model")
    assert beats(_lease(0.8, 0.5), None) and not beats(_lease(0.8, 0.5), _lease(0.7, 0.5))


def test_bad_lease_settings_are_refused(capsys):
    from workbench.cli.stream_lease import main

    assert main(["run", "--deadline-s", "100", "--validate-s", "100"]) == 2
    assert "validate_s must lie in (0, deadline_s" in capsys.readouterr().err
    assert main(["run", "--batch-size", "0"]) == 2
    assert "batch_size must be positive" in capsys.readouterr().err


@pytest.mark.slow
def test_one_lease_on_the_cpu_trains_validates_and_brings_back_a_loadable_checkpoint(tmp_path):
    """The device's lease end to end on the CPU: about 6 minutes here."""
    import subprocess

    out = tmp_path / "lease"
    done = subprocess.run([sys.executable, "-m", "workbench.cli.stream_lease", "run", "--out", str(out),
                           "--device", "cpu", "--deadline-s", "300", "--validate-s", "120", "--batch-size", "2",
                           "--samples-per-task", "4", "--save-freq", "4", "--log-freq", "2", "--val-tasks", "2",
                           "--val-frames-per-task", "2", "--generate-workers", "1"],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    lease = json.loads((out / "lease.json").read_text())
    assert lease["steps"] >= 4 and lease["samples"] == 2 * lease["steps"] and lease["first_step_s"] < 120
    assert set(lease["validation"]) == {"moved", "one_layout"}
    assert len(list(out.iterdir())) <= 8  # what one device call brings back
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    InstantPolicyPolicy.from_pretrained(out)
