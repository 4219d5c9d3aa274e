"""``lerobot-ip-bench``: the benchmarks print measured JSON, compare one variant at a time, refuse bad sizes."""

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


def test_train_step_benchmark_compares_fused_and_loop_adamw_on_the_ladder_recipe(capsys):
    from lerobot_instant_policy.cli.bench import main

    assert main(["train-step", "--batch-size", "2", "--repeats", "1", "--reencode-action-clouds", "false",
                 "--action-scene-graph", "false", "--num-frequencies", "4", "--compare-fused-adamw", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["figure"] == "samples_per_s" and "fused_adamw" not in result
    assert result["action_scene_graph"] is False and result["num_frequencies"] == 4
    assert len(result["runs_fused"]) == len(result["runs_loop"]) == 3
    assert min(result["runs_fused"] + result["runs_loop"]) > 0
    assert result["fused_over_loop"] == round(result["fused"] / result["loop"], 3)


def fake_timing(monkeypatch, bench: str, option: str, figure: str, on: float, off: float) -> list[dict]:
    """Replace ``bench_policy.<bench>`` by a fake whose ``figure`` is ``on`` or ``off`` as the config ``option`` is;
    returns the keyword arguments of every call, in order."""
    from lerobot_instant_policy.benchmarks import policy as bench_policy

    seen = []

    def fake_bench(preset, **kwargs):
        seen.append(kwargs)
        return {"benchmark": bench, option: kwargs[option], figure: on if kwargs[option] else off}

    monkeypatch.setattr(bench_policy, bench, fake_bench)
    return seen


def test_train_step_benchmark_alternates_compiled_and_eager_layers(capsys, monkeypatch):
    """``--compare-compile-model`` hands ``compile_model`` to the config in alternation (the compiled training step
    itself is tested equal to the eager one in test_instant_policy_policy.py; compiling the small preset takes
    minutes, so the timing is faked here)."""
    from lerobot_instant_policy.cli.bench import main

    seen = fake_timing(monkeypatch, "bench_train_step", "compile_model", "samples_per_s", 2.0, 1.0)
    assert main(["train-step", "--batch-size", "8", "--amp", "true", "--compare-compile-model", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [kwargs["compile_model"] for kwargs in seen] == [True, False] * 3
    assert all(kwargs["use_amp"] and kwargs["batch_size"] == 8 for kwargs in seen)
    assert result["compiled_over_eager"] == 2.0 and "compile_model" not in result
    assert main(["train-step", "--compile-model", "true", "--json"]) == 0
    assert seen[-1]["compile_model"] is True


@pytest.mark.parametrize("flag, option, on_name, off_name, ratio", [
    ("--compare-frame-cache", "frame_cache", "cached", "live", "cached_over_live"),
    ("--compare-amp", "use_amp", "amp", "float32", "amp_over_float32"),
])
def test_train_step_benchmark_alternates_the_compared_option(capsys, monkeypatch, flag, option, on_name, off_name,
                                                            ratio):
    """``--compare-frame-cache`` and ``--compare-amp`` hand their option to the config in alternation, the rest of
    the settings unchanged (the real timing runs in the AdamW comparison above; cached scene nodes are tested equal to
    live encoding in test_frame_encodings.py, training under autocast in test_mixed_precision.py; autocast is 8x
    slower than float32 on CPUs without bfloat16 kernels, so the timing is faked here)."""
    from lerobot_instant_policy.cli.bench import main

    seen = fake_timing(monkeypatch, "bench_train_step", option, "samples_per_s", 3.0, 2.0)
    assert main(["train-step", "--batch-size", "2", "--num-frequencies", "6", flag, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [kwargs[option] for kwargs in seen] == [True, False] * 3
    assert all(kwargs["batch_size"] == 2 and kwargs["num_frequencies"] == 6 for kwargs in seen)
    assert result["figure"] == "samples_per_s" and option not in result
    assert len(result[f"runs_{on_name}"]) == len(result[f"runs_{off_name}"]) == 3
    assert result[on_name] == 3.0 and result[off_name] == 2.0 and result[ratio] == 1.5


def test_inference_benchmark_alternates_compiled_and_eager_sampling(capsys, monkeypatch):
    """``--compare-compile-inference`` hands ``compile_inference`` to the config in alternation (compiled sampling is
    tested equal to eager sampling in test_instant_policy_policy.py; the timing is faked here)."""
    from lerobot_instant_policy.cli.bench import main

    seen = fake_timing(monkeypatch, "bench_inference", "compile_inference", "ms_per_control_step", 10.0, 15.0)
    assert main(["inference", "--action-scene-graph", "false", "--compare-compile-inference", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [kwargs["compile_inference"] for kwargs in seen] == [True, False] * 3
    assert all(kwargs["action_scene_graph"] is False for kwargs in seen)
    assert result["compiled"] == 10.0 and result["eager"] == 15.0 and "compile_inference" not in result
    assert result["compiled_over_eager"] == round(10.0 / 15.0, 3)
    assert main(["inference", "--compile-inference", "true", "--json"]) == 0
    assert seen[-1]["compile_inference"] is True
    with pytest.raises(SystemExit) as exit_info:
        main(["inference", "--compare-compile-inference", "--compare-dense-attention"])
    assert exit_info.value.code == 2 and "compare one variant at a time" in capsys.readouterr().err


def test_train_step_benchmark_compares_one_variant_at_a_time(capsys):
    from lerobot_instant_policy.cli.bench import main

    with pytest.raises(SystemExit) as exit_info:
        main(["train-step", "--compare-amp", "--compare-compile-model"])
    assert exit_info.value.code == 2
    assert "compare one variant at a time" in capsys.readouterr().err


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
              "--tasks-per-render", "1", "--zbuffer", "160", "120", "--device", "cpu", "--json"]
    assert main(["stream", *common]) == 0
    stream = json.loads(capsys.readouterr().out)
    assert stream["source"] == "stream" and stream["steps"] == 2 and stream["hidden_dim"] == 128
    assert stream["samples_per_s"] == pytest.approx(4 / stream["wall_s"])
    assert stream["distinct_tasks"] == 2 and 0 < stream["update_share"] < 1  # 2 samples a task, 4 samples
    assert stream["stream"]["zbuffer"] == "160x120"
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
