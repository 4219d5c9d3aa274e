"""``python -m workbench.cli.bench inference|train-step --compare-*``: one setting of the installed benchmark on and
off in alternation, its medians and their ratio; one comparison at a time."""

from __future__ import annotations

import json

import pytest

from workbench.cli.bench import main


def test_train_step_compares_fused_and_loop_adamw_on_the_ladder_recipe(capsys):
    assert main(["train-step", "--batch-size", "2", "--repeats", "1", "--reencode-action-clouds", "false",
                 "--action-scene-graph", "false", "--num-frequencies", "4", "--compare-fused-adamw", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["figure"] == "samples_per_s" and "fused_adamw" not in result
    assert result["action_scene_graph"] is False and result["num_frequencies"] == 4
    assert len(result["runs_fused"]) == len(result["runs_loop"]) == 3
    assert min(result["runs_fused"] + result["runs_loop"]) > 0
    assert result["fused_over_loop"] == round(result["fused"] / result["loop"], 3)


def fake_timing(monkeypatch, bench: str, option: str, figure: str, on: float, off: float) -> list[dict]:
    """Replace the installed ``<bench>`` that :mod:`workbench.benchmarks.variants` runs by a fake whose ``figure`` is
    ``on`` or ``off`` as the config ``option`` is; returns the keyword arguments of every call, in order."""
    from workbench.benchmarks import variants

    seen = []

    def fake_bench(preset, **kwargs):
        seen.append(kwargs)
        return {"benchmark": bench, option: kwargs[option], figure: on if kwargs[option] else off}

    monkeypatch.setattr(variants, bench, fake_bench)
    return seen


def test_train_step_alternates_compiled_and_eager_layers(capsys, monkeypatch):
    """``--compare-compile-model`` hands ``compile_model`` to the config in alternation (the compiled training step
    itself is tested equal to the eager one in test_instant_policy_policy.py; compiling the small preset takes
    minutes, so the timing is faked here)."""
    seen = fake_timing(monkeypatch, "bench_train_step", "compile_model", "samples_per_s", 2.0, 1.0)
    assert main(["train-step", "--batch-size", "8", "--amp", "true", "--compare-compile-model", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [kwargs["compile_model"] for kwargs in seen] == [True, False] * 3
    assert all(kwargs["use_amp"] and kwargs["batch_size"] == 8 for kwargs in seen)
    assert result["compiled_over_eager"] == 2.0 and "compile_model" not in result


@pytest.mark.parametrize("flag, option, on_name, off_name, ratio", [
    ("--compare-frame-cache", "frame_cache", "cached", "live", "cached_over_live"),
    ("--compare-amp", "use_amp", "amp", "float32", "amp_over_float32"),
])
def test_train_step_alternates_the_compared_option(capsys, monkeypatch, flag, option, on_name, off_name, ratio):
    """``--compare-frame-cache`` and ``--compare-amp`` hand their option to the config in alternation, the rest of
    the settings unchanged (the real timing runs in the AdamW comparison above; cached scene nodes are tested equal to
    live encoding in test_frame_encodings.py, training under autocast in test_mixed_precision.py; autocast is 8x
    slower than float32 on CPUs without bfloat16 kernels, so the timing is faked here)."""
    seen = fake_timing(monkeypatch, "bench_train_step", option, "samples_per_s", 3.0, 2.0)
    assert main(["train-step", "--batch-size", "2", "--num-frequencies", "6", flag, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [kwargs[option] for kwargs in seen] == [True, False] * 3
    assert all(kwargs["batch_size"] == 2 and kwargs["num_frequencies"] == 6 for kwargs in seen)
    assert result["figure"] == "samples_per_s" and option not in result
    assert len(result[f"runs_{on_name}"]) == len(result[f"runs_{off_name}"]) == 3
    assert result[on_name] == 3.0 and result[off_name] == 2.0 and result[ratio] == 1.5


def test_inference_alternates_compiled_and_eager_sampling(capsys, monkeypatch):
    """``--compare-compile-inference`` hands ``compile_inference`` to the config in alternation (compiled sampling is
    tested equal to eager sampling in test_instant_policy_policy.py; the timing is faked here)."""
    seen = fake_timing(monkeypatch, "bench_inference", "compile_inference", "ms_per_control_step", 10.0, 15.0)
    assert main(["inference", "--action-scene-graph", "false", "--compare-compile-inference", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert [kwargs["compile_inference"] for kwargs in seen] == [True, False] * 3
    assert all(kwargs["action_scene_graph"] is False for kwargs in seen)
    assert result["compiled"] == 10.0 and result["eager"] == 15.0 and "compile_inference" not in result
    assert result["compiled_over_eager"] == round(10.0 / 15.0, 3)


@pytest.mark.parametrize("argv", [["inference", "--compare-compile-inference", "--compare-dense-attention"],
                                  ["train-step", "--compare-amp", "--compare-compile-model"],
                                  ["train-step", "--amp", "true"]])
def test_one_comparison_at_a_time(capsys, argv):
    """Two ``--compare-*`` flags, or none (one setting alone is ``lerobot-ip-bench``'s), are a usage error."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert "compare one variant at a time" in error and f"lerobot-ip-bench {argv[0]}" in error


def test_a_compared_setting_refuses_bad_sizes_as_the_installed_one_does(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["train-step", "--batch-size", "0", "--compare-amp"])
    assert exit_info.value.code == 2
    assert "--repeats and --batch-size must be positive" in capsys.readouterr().err
