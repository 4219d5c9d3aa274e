"""``python -m workbench.cli.bench``: the development benchmarks print measured JSON and refuse bad sizes."""

from __future__ import annotations

import json

import pytest
from synthetic_demos import object_pose, write_demo_dataset

from workbench.cli.bench import main

REPO = "local/ip_bench_data"


def test_data_benchmark_times_both_paths_on_the_same_rows(tmp_path, capsys):
    from lerobot.datasets import LeRobotDataset

    root = tmp_path / "data"
    write_demo_dataset(root, REPO, [("lift", object_pose(0.5, 0.0, 0.0)), ("lift", object_pose(0.45, 0.1, 20.0)),
                                    ("lift", object_pose(0.4, 0.15, 55.0))])
    frames = LeRobotDataset(REPO, root=root).num_frames
    assert main(["data", "--root", str(root), "--repo-id", REPO, "--rows", "6", "--repeats", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["benchmark"] == "data" and result["frames"] == frames
    assert len(result["runs_delta_timestamps"]) == len(result["runs_action_table"]) == 2
    assert min(result["runs_delta_timestamps"] + result["runs_action_table"]) > 0
    # The ratio of the unrounded medians; the printed medians are rounded to 0.01 ms.
    assert result["speedup"] == pytest.approx(result["ms_per_row_delta_timestamps"] / result["ms_per_row_action_table"],
                                              rel=0.05)


def test_encoder_benchmark_times_both_presets_and_refuses_no_repeats(capsys):
    assert main(["encoder", "--repeats", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["num_points"] == 2048 and result["repeats"] == 1
    rates = [value for key, value in result.items() if key.endswith("_clouds_per_s")]
    assert len(rates) >= 2 and min(rates) > 0
    with pytest.raises(SystemExit):
        main(["encoder", "--repeats", "0"])
    assert "--repeats must be positive" in capsys.readouterr().err
