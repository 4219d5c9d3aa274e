"""``python -m workbench.cli.bench lerobot-train``: the real ``lerobot-train`` on a dataset the test writes, its log
lines read."""

from __future__ import annotations

import json

import pytest
from synthetic_demos import object_pose, write_demo_dataset

from workbench.benchmarks.lerobot_train import LogLine, bench_lerobot_train, parse_log_line, summarize
from workbench.cli.bench import main

# A line as lerobot-train 0.6.1 writes it: tqdm's bar, a carriage return, then LeRobot's log record.
LOGGED = ("Training:  50%|#####     | 249/500 [00:49<00:25,  9.91step/s]\rINFO 2026-11-25 12:08:17 ot_train.py:641 "
          "step:1K smpl:8K ep:52 epch:0.04 loss:0.041 grdn:0.326 lr:7.7e-04 updt_s:0.100 data_s:0.005 smp/s:76 "
          "translation:0.033 rotation:0.008\n")


def test_a_log_line_gives_its_step_and_window_averages():
    assert parse_log_line(LOGGED, 3.5) == LogLine(1000, 0.100, 0.005, 3.5)
    assert parse_log_line("INFO step:250 smpl:2K updt_s:0.099 data_s:0.004 smp/s:77", 0.0).step == 250
    assert parse_log_line("Training:  50%|#####     | 249/500 [00:49<00:25,  9.91step/s]", 0.0) is None
    assert parse_log_line("INFO Creating dataset", 0.0) is None


def test_throughput_counts_only_lines_after_the_warm_up():
    lines = [LogLine(50, 9.0, 1.0, 0.0), LogLine(100, 0.10, 0.01, 60.0), LogLine(150, 0.08, 0.01, 64.0),
             LogLine(200, 0.09, 0.02, 68.0)]
    figures = summarize(lines, batch_size=8, skip=50)
    assert figures["samples_per_s_wall"] == 8 * 100 / 8.0  # steps 100 -> 200 in 8 s; the compiling window is out
    assert figures["updt_s"] == 0.09 and figures["data_s"] == 0.01 and figures["log_lines"] == 3
    with pytest.raises(ValueError, match="1 log lines after step 150"):
        summarize(lines, batch_size=8, skip=150)


@pytest.mark.slow  # CI: the paths it runs are tested elsewhere; kept out of the 10-minute suite
def test_runs_lerobot_train_per_variant_and_reports_ratios(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path / "tmp"))
    write_demo_dataset(tmp_path / "data", "local/bench_train", [
        ("lift", object_pose(0.5, 0.0, 0.0)), ("lift", object_pose(0.45, 0.1, 20.0)),
        ("push", object_pose(0.55, -0.1, -40.0)), ("push", object_pose(0.4, 0.15, 55.0))])
    assert main(["lerobot-train", "--root", str(tmp_path / "data"), "--steps", "9", "--skip", "3", "--log-every", "3",
                 "--batch-size", "2", "--threads", "1", "--num-workers", "0", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["benchmark"] == "lerobot-train" and result["batch"] == 2
    assert [variant["num_workers"] for variant in result["variants"]] == [0, 1]
    for variant in result["variants"]:
        assert variant["samples_per_s_wall"] > 0 and variant["updt_s"] > 0 and variant["data_s"] >= 0
        assert variant["omp_wait_policy"] == "default" and len(variant["runs_samples_per_s_wall"]) == 1
    second = result["variants"][1]
    assert second["over_first"] == round(second["samples_per_s_wall"] / result["variants"][0]["samples_per_s_wall"], 3)
    assert not list((tmp_path / "tmp").iterdir())  # the runs' output directories are removed


def test_a_failing_run_raises_with_lerobot_trains_output(tmp_path):
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "info.json").write_text("{}")
    with pytest.raises(RuntimeError, match="lerobot-train exited with"):
        bench_lerobot_train(str(tmp_path), steps=4, skip=1, log_every=1, threads=1)


def test_bad_arguments_are_refused_before_anything_runs(tmp_path, capsys):
    with pytest.raises(FileNotFoundError, match="is not a LeRobotDataset"):
        bench_lerobot_train(str(tmp_path / "missing"))
    (tmp_path / "meta").mkdir()
    (tmp_path / "meta" / "info.json").write_text("{}")
    with pytest.raises(ValueError, match="unknown OpenMP wait policies \\['spin'\\]"):
        bench_lerobot_train(str(tmp_path), omp_wait_policies=("active", "spin"))
    with pytest.raises(SystemExit) as exit_info:
        main(["lerobot-train", "--root", str(tmp_path), "--steps", "100", "--skip", "100"])
    assert exit_info.value.code == 2 and "--skip (100) must be below --steps (100)" in capsys.readouterr().err
