"""``lerobot-ip-bench``: the benchmarks print measured JSON of one setting and refuse bad sizes."""

from __future__ import annotations

import json

import pytest


@pytest.mark.slow  # CI: the paths it runs are tested elsewhere; kept out of the 10-minute suite
def test_generate_benchmark_prints_measured_json(capsys):
    from lerobot_instant_policy.cli.bench import main

    assert main(["generate", "--tasks", "1", "--workers", "1", "--repeats", "1", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["benchmark"] == "generate"
    assert result["frames_per_s_one_worker"] > 0 and result["frames_per_s_total"] > 0
    assert len(result["runs_frames_per_s_one_worker"]) == 1


def test_train_step_benchmark_times_one_setting_of_the_ladder_recipe(capsys):
    from lerobot_instant_policy.cli.bench import main

    assert main(["train-step", "--batch-size", "2", "--repeats", "1", "--reencode-action-clouds", "false",
                 "--action-scene-graph", "false", "--num-frequencies", "4", "--fused-adamw", "false", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["benchmark"] == "train-step" and result["batch"] == 2 and result["samples_per_s"] > 0
    assert result["action_scene_graph"] is False and result["num_frequencies"] == 4 and result["fused_adamw"] is False
    assert result["frame_cache"] is True and result["use_amp"] is False and len(result["runs_s_per_step"]) == 1


def fake_bench(monkeypatch, bench: str) -> list[dict]:
    """Replace ``bench_policy.<bench>`` by a fake that records its keyword arguments, in order."""
    from lerobot_instant_policy.benchmarks import policy as bench_policy

    seen = []
    monkeypatch.setattr(bench_policy, bench, lambda preset, **kwargs: seen.append(kwargs) or {"benchmark": bench})
    return seen


def test_single_setting_flags_reach_the_benchmarks(capsys, monkeypatch):
    """``--compile-model``, ``--amp``, ``--frame-cache``, ``--dense-attention`` and ``--compile-inference`` set their
    option for the one run (compiling the small preset takes minutes, so the benchmark is faked here)."""
    from lerobot_instant_policy.cli.bench import main

    seen = fake_bench(monkeypatch, "bench_train_step")
    assert main(["train-step", "--batch-size", "8", "--amp", "true", "--compile-model", "true", "--frame-cache",
                 "false", "--dense-attention", "false", "--json"]) == 0
    assert seen == [{"batch_size": 8, "repeats": 5, "use_amp": True, "compile_model": True, "frame_cache": False,
                     "dense_attention": False}]
    seen = fake_bench(monkeypatch, "bench_inference")
    assert main(["inference", "--compile-inference", "true", "--json"]) == 0
    assert seen == [{"repeats": 5, "policy_path": None, "compile_inference": True}]
    capsys.readouterr()


@pytest.mark.parametrize("argv, message", [
    (["inference", "--compare-dense-attention"], "unrecognized arguments: --compare-dense-attention"),
    (["train-step", "--compare-amp"], "unrecognized arguments: --compare-amp"),
    (["lerobot-train", "--root", "data"], "invalid choice: 'lerobot-train'"),
])
def test_the_comparisons_are_not_installed(capsys, argv, message):
    """Two settings in alternation and ``lerobot-train`` end to end are the workbench's (``python -m
    workbench.cli.bench``)."""
    from lerobot_instant_policy.cli.bench import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--batch-size", "--repeats"])
def test_train_step_benchmark_refuses_non_positive_sizes(capsys, flag):
    from lerobot_instant_policy.cli.bench import main

    with pytest.raises(SystemExit) as exit_info:
        main(["train-step", flag, "0"])
    assert exit_info.value.code == 2
    assert "--repeats and --batch-size must be positive" in capsys.readouterr().err


def test_env_benchmark_times_steps_observations_and_a_video_frame_per_render_size(capsys):
    from lerobot_instant_policy.cli.bench import main

    assert main(["env", "--steps", "3", "--repeats", "1", "--video-sizes", "64", "16", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["benchmark"] == "env" and result["steps_per_s"] > 0 and result["observation_render_ms"] > 0
    assert set(result["video_frame_ms"]) == {"64", "16"} and min(result["video_frame_ms"].values()) > 0
    with pytest.raises(SystemExit):
        main(["env", "--video-sizes", "0"])
    assert "--video-sizes must be positive" in capsys.readouterr().err


def test_inference_benchmark_times_the_mean_of_several_samples(capsys):
    from lerobot_instant_policy.cli.bench import main

    assert main(["inference", "--repeats", "1", "--samples-per-prediction", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["samples_per_prediction"] == 3 and result["ms_per_control_step"] > 0
    with pytest.raises(SystemExit):
        main(["inference", "--samples-per-prediction", "0"])
    assert "--samples-per-prediction must be positive" in capsys.readouterr().err


def test_stream_and_pool_benchmarks_time_whole_runs_with_every_render_inside(capsys, tmp_path):
    """Wall time over the run: samples per second are the updated samples over it; the pool's generator process
    starts inside it (its first tasks' renders are waited for), and its account matches the samples drawn."""
    from lerobot_instant_policy.cli.bench import main

    config = tmp_path / "stream.json"
    config.write_text(json.dumps({"seed": 3, "object_pool": ["pb/cube", "pb/duck"]}))
    common = ["--config", str(config), "--batch-size", "2", "--steps", "2", "--samples-per-task", "2",
              "--tasks-per-render", "1", "--zbuffer", "160", "120", "--surface-samples", "1024", "--device", "cpu",
              "--json"]
    assert main(["stream", *common]) == 0
    stream = json.loads(capsys.readouterr().out)
    assert stream["source"] == "stream" and stream["steps"] == 2 and stream["hidden_dim"] == 128
    assert stream["samples_per_s"] == pytest.approx(4 / stream["wall_s"])
    assert stream["distinct_tasks"] == 2 and 0 < stream["update_share"] < 1  # 2 samples a task, 4 samples
    assert stream["stream"]["zbuffer"] == "160x120" and stream["stream"]["surface_samples"] == 1024
    assert main(["pool", *common, "--min-tasks", "2"]) == 0
    pool = json.loads(capsys.readouterr().out)
    assert pool["source"] == "pool" and pool["pool"]["samples"] == 4 and pool["generators"] == 1
    assert pool["pool"]["waited_s"] > 0 and pool["wall_s"] > pool["pool"]["waited_s"]
    assert pool["distinct_tasks"] == pool["pool"]["distinct_tasks_used"] >= 2
    assert pool["fresh_tasks_per_s"] == pytest.approx(pool["distinct_tasks"] / pool["wall_s"])


def test_stream_benchmark_refuses_non_positive_sizes(capsys):
    from lerobot_instant_policy.cli.bench import main

    with pytest.raises(SystemExit) as exit_info:
        main(["stream", "--steps", "0"])
    assert exit_info.value.code == 2
    assert "must be positive" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["pool", "--capacity", "4", "--min-tasks", "5"])
    assert "must not exceed capacity" in capsys.readouterr().err


def test_the_priors_benchmark_times_both_variants_on_the_same_tasks(capsys, tmp_path):
    """Seconds per task of a generator's work without and with replay priors, alternating blocks of the same tasks:
    the ratio is of the two medians, the task rate its inverse."""
    from lerobot_instant_policy.cli.bench import main

    config = tmp_path / "stream.json"
    config.write_text(json.dumps({"seed": 3, "object_pool": ["pb/cube", "pb/duck"]}))
    assert main(["priors", "--config", str(config), "--tasks", "2", "--samples-per-task", "1",
                 "--surface-samples", "1024", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    seconds = result["seconds_per_task"]
    assert result["blocks"] == 2 and seconds["with"] > 0 and seconds["without"] > 0
    assert result["ratio_with_to_without"] == pytest.approx(seconds["with"] / seconds["without"])
    assert result["task_rate_with_priors"] == pytest.approx(1 / result["ratio_with_to_without"])
    assert result["stream"]["surface_samples"] == 1024
    with pytest.raises(SystemExit):
        main(["priors", "--tasks", "0"])
