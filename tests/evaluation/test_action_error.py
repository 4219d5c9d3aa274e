"""``lerobot-ip-action-error``: offline action error of the shipped checkpoint at one setting of K, N and L on 2
held-out pseudo-tasks (the sweep over several settings is the workbench's, tested in
workbench/tests/test_action_error_sweep.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lerobot_instant_policy.cli.action_error import main as action_error_main
from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT
from lerobot_instant_policy.evaluation import action_error as ae
from lerobot_instant_policy.evaluation.checkpoints import EvaluationError

SHIPPED = SHIPPED_CHECKPOINT

pytestmark = pytest.mark.usefixtures("single_torch_thread")


@pytest.fixture(scope="module")
def held_out_root(held_out_pseudo_tasks):
    """Held-out pseudo-tasks × 3 demonstrations (conftest's, shared with test_shipped_checkpoint.py); the tests here
    read their first 2 tasks."""
    return held_out_pseudo_tasks


def _run(root, **overrides):
    settings = dict(tasks=2, frames_per_task=1, seed=0, k=4, n=2, l=10, untrained=False)
    return ae.action_error(SHIPPED, root, **{**settings, **overrides})


def test_action_error_structure_and_determinism(held_out_root, monkeypatch):
    from lerobot_instant_policy.model.instant_policy_network import InstantPolicyNetwork

    denoise, calls = InstantPolicyNetwork.denoise, []
    monkeypatch.setattr(InstantPolicyNetwork, "denoise", lambda self, *a, **k: calls.append(1) or denoise(self, *a, **k))
    first = _run(held_out_root)
    # K = 4 on 2 frames, then the K = 4 swap on 2 frames: each prediction denoised exactly K times
    assert len(calls) == 2 * 4 + 2 * 4
    again = _run(held_out_root)
    (own,) = first["settings"]
    assert (own["K"], own["N"], own["L"]) == (4, 2, 10) and "untrained" not in first
    assert first["tasks"] == 2 and first["frames"] == 2 and first["horizon_T"] == 8
    for row in first["settings"] + [first["hold"], first["swap"]]:
        for key in ("translation_mm", "translation_mm_first_step", "rotation_deg", "gripper_accuracy"):
            assert math.isfinite(row[key]) and row[key] >= 0, (key, row)
        assert 0 <= row["gripper_accuracy"] <= 1 and row["steps"] == 8 * row["frames"]
    strip = [{k: v for k, v in row.items() if k != "ms_per_prediction"} for row in first["settings"]]
    assert strip == [{k: v for k, v in row.items() if k != "ms_per_prediction"} for row in again["settings"]]
    # the swap runs the same frames and noise with the other task's demonstrations: a different prediction
    assert first["swap"]["frames"] == 2 and (first["swap"]["K"], first["swap"]["N"], first["swap"]["L"]) == (4, 2, 10)
    assert (first["swap"]["translation_mm"], first["swap"]["rotation_deg"]) != (own["translation_mm"],
                                                                              own["rotation_deg"])
    assert first["context_gain"]["translation"] == round(first["swap"]["translation_mm"] / own["translation_mm"], 3)
    assert set(first["phases"]) == set(ae.THIRDS)
    assert sum(row["frames"] for row in first["phases"].values()) == first["frames"]
    # per task: the frames of each, pooling back to the whole; the intervals over the two tasks; paired with itself
    assert [row["task"] for row in first["per_task"]] == [row["task"] for row in again["per_task"]]
    assert [row["frames"] for row in first["per_task"]] == [1, 1]
    for per_task_key, row in (("own_mm", own), ("hold_mm", first["hold"]), ("swap_mm", first["swap"])):
        pooled = sum(task[per_task_key] * task["frames"] for task in first["per_task"]) / first["frames"]
        assert pooled == pytest.approx(row["translation_mm"], abs=0.01), per_task_key
    intervals = first["intervals"]
    assert (intervals["unit"], intervals["clusters"], intervals["resamples"]) == ("task", 2, ae.BOOTSTRAP_RESAMPLES)
    for name in ae.RATIOS:
        low, high = intervals[name]
        assert low <= high
    assert intervals == again["intervals"]
    same = ae.paired_ratio_difference(first, again)
    assert all(same[name]["difference"] == 0.0 and same[name]["ci95"] == [0.0, 0.0] for name in ae.RATIOS)
    json.dumps(first)


def test_context_swap_gives_each_task_the_next_tasks_demonstrations(held_out_root):
    tasks = ae.load_held_out_tasks(held_out_root, 2, 1, 8, seed=0)
    swapped = ae.swapped_context(tasks)
    for index, held in enumerate(swapped):
        other = tasks[1 - index]
        assert held.task == tasks[index].task and held.frames is tasks[index].frames
        assert all(demo.task == held.task for demo in held.demos)
        assert all(np.array_equal(a.state, b.state) for a, b in zip(held.demos, other.demos, strict=True))
    with pytest.raises(ae.ActionErrorError, match="at least 2 pseudo-tasks"):
        ae.swapped_context(tasks[:1])
    gain = ae.context_gain({"translation_mm": 10.0, "rotation_deg": 2.0, "gripper_accuracy": 0.9},
                           {"translation_mm": 25.0, "rotation_deg": 2.0, "gripper_accuracy": 0.6})
    assert gain == {"translation": 2.5, "rotation": 1.0, "gripper": 4.0}


def test_k_changes_the_prediction_itself(held_out_root):
    policy = ae.InstantPolicyPolicy.from_pretrained(SHIPPED).eval()
    (task,) = ae.load_held_out_tasks(held_out_root, 1, 1, policy.config.horizon, seed=0)
    policy.set_demonstrations(task.demos[:2], num_waypoints=10)
    one = ae.predict_task(policy, task, 1, 2)
    four = ae.predict_task(policy, task, 4, 2)
    four_again = ae.predict_task(policy, task, 4, 2)
    assert not np.allclose(one[0], four[0]) and np.array_equal(four[0], four_again[0])
    assert policy.config.inference_steps == 4  # K is an argument: the loaded config is left as it was


def test_chunk_errors_measure_known_offsets():
    target = np.tile(np.array([0.5, 0.0, 0.2, 0.0, 0.0, 0.0, 1.0, 1.0]), (3, 1))
    predicted = target.copy()
    predicted[:, 0] += 0.01  # 10 mm
    predicted[:, 3:7] = [0.0, 0.0, math.sin(math.radians(15)), math.cos(math.radians(15))]  # 30° about z
    predicted[2, 7] = 0.0
    errors = ae.chunk_errors(predicted, target)
    assert np.allclose(errors["translation_mm"], 10.0) and np.allclose(errors["rotation_deg"], 30.0)
    assert errors["gripper_correct"].tolist() == [True, True, False]
    negated = target.copy()
    negated[:, 3:7] *= -1
    assert np.allclose(ae.chunk_errors(negated, target)["rotation_deg"], 0.0, atol=1e-5)


def test_samples_per_prediction_reaches_every_prediction_from_the_command_line(held_out_root, monkeypatch, capsys):
    """``--samples-per-prediction 3``: every prediction (own, swap) samples 3 rows per frame and predicts their
    mean; reported in the JSON; a value outside 1…64 is refused before the checkpoint loads."""
    from lerobot_instant_policy.model.instant_policy_network import InstantPolicyNetwork

    sample, counts = InstantPolicyNetwork.sample_actions, []
    monkeypatch.setattr(InstantPolicyNetwork, "sample_actions",
                        lambda self, *a, **k: counts.append(k["num_samples"]) or sample(self, *a, **k))
    assert action_error_main(["--policy-path", str(SHIPPED), "--root", str(held_out_root), "--tasks", "2",
                              "--frames-per-task", "1", "--K", "1", "--N", "2", "--L", "10", "--no-untrained",
                              "--samples-per-prediction", "3"]) == 0
    printed = capsys.readouterr()
    result = json.loads(printed.out)
    assert result["samples_per_prediction"] == 3 and counts == [3] * 4  # 2 frames own, 2 swapped
    # without --json, a line for a reader follows on stderr: each ratio with its interval over tasks
    low, high = result["intervals"]["vs_holding_still"]
    assert f"x holding still [{low:.3f}, {high:.3f}]" in printed.err and "over 2 tasks" in printed.err
    assert math.isfinite(result["settings"][0]["translation_mm"])
    assert action_error_main(["--policy-path", str(SHIPPED), "--root", str(held_out_root),
                              "--samples-per-prediction", "0"]) == 2
    assert "samples_per_prediction (S) must be an integer in the supported range 1…64" in capsys.readouterr().err


def test_the_command_line_gives_the_figures_a_training_run_reads(held_out_root, capsys):
    """The command line ``workbench/standing.py`` runs (one setting, no untrained reference, the device named)
    prints JSON with the own error, holding still's and the context gain."""
    assert action_error_main(["--policy-path", str(SHIPPED), "--root", str(held_out_root), "--repo-id", "local/val",
                              "--tasks", "2", "--frames-per-task", "1", "--K", "4", "--N", "2", "--L", "10",
                              "--no-untrained", "--json", "--device", "cpu"]) == 0
    printed = capsys.readouterr()
    result = json.loads(printed.out)
    assert "x holding still" not in printed.err  # --json: the JSON alone
    assert result["settings"][0]["translation_mm"] > 0 and result["hold"]["translation_mm"] > 0
    assert result["context_gain"]["translation"] == round(
        result["swap"]["translation_mm"] / result["settings"][0]["translation_mm"], 3)


def test_bad_inputs_give_clear_errors(held_out_root, tmp_path, capsys, monkeypatch):
    with pytest.raises(ae.ActionErrorError, match=r"N can be at most 2"):
        _run(held_out_root, n=3)
    with pytest.raises(EvaluationError, match="does not exist"):
        _run(tmp_path / "missing")
    code = action_error_main(["--policy-path", str(SHIPPED), "--root", str(tmp_path / "missing"), "--json"])
    assert code == 2 and "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:  # one setting: a list is the workbench's sweep
        action_error_main(["--policy-path", str(SHIPPED), "--root", str(held_out_root), "--K", "1,2,4,8"])
    assert exit_info.value.code == 2 and "workbench.cli.action_error_sweep" in capsys.readouterr().err


@pytest.mark.parametrize("setting, message", [
    (dict(k=0), r"inference_steps \(K\) must be an integer in the supported range 1…8, got 0"),
    (dict(k=9), r"inference_steps \(K\) must be an integer in the supported range 1…8, got 9"),
    (dict(n=0), r"num_demos \(N\) must be an integer in the supported range 1…8, got 0"),
    (dict(l=1), r"num_waypoints \(L\) must be an integer in the supported range 2…32, got 1"),
    (dict(samples_per_prediction=65), r"samples_per_prediction \(S\) must be an integer in the supported range 1…64"),
])
def test_k_n_l_and_s_are_judged_by_the_configs_range_check_before_the_weights_load(held_out_root, monkeypatch,
                                                                                   setting, message):
    """One range check for K, N, L and S: the config's (model/bounds.py, run when a config is built), its message."""
    monkeypatch.setattr(ae, "load_policy", lambda *args, **kwargs: pytest.fail("the weights were loaded"))
    with pytest.raises(ae.ActionErrorError, match=message):
        _run(held_out_root, **setting)


def test_phases_split_the_live_episodes_into_thirds_and_pool_back_to_the_whole(held_out_root):
    tasks = ae.load_held_out_tasks(held_out_root, num_tasks=2, frames_per_task=10_000, horizon=8, seed=0,
                                   repo_id="local/val")
    for held in tasks:  # every frame of the live episode: thirds in order, sizes within one frame of each other
        phases = [frame.phase for frame in held.frames]
        assert [frame.t for frame in held.frames] == list(range(len(phases)))
        assert phases == sorted(phases) and set(phases) == {0, 1, 2}
        assert max(phases.count(p) for p in range(3)) - min(phases.count(p) for p in range(3)) <= 1
    hold = ae.hold_reference(tasks)
    by_phase = hold["by_phase"]
    assert sum(row["frames"] for row in by_phase.values()) == hold["frames"]
    pooled = sum(row["frames"] * row["translation_mm"] for row in by_phase.values()) / hold["frames"]
    assert pooled == pytest.approx(hold["translation_mm"], abs=0.01)


def test_phase_table_compares_own_hold_and_swap_per_third():
    def row(*mm):
        return {"by_phase": {name: {"translation_mm": value, "frames": 5 if value is not None else 0}
                             for name, value in zip(ae.THIRDS, mm)}}

    table = ae.phase_table(row(10.0, 20.0, None), row(40.0, 20.0, None), row(30.0, 30.0, None))
    assert table["first_third"] == {"frames": 5, "own_mm": 10.0, "hold_mm": 40.0, "swap_mm": 30.0,
                                    "over_hold": 0.25, "context_gain": 3.0}
    assert table["middle_third"]["over_hold"] == 1.0 and table["middle_third"]["context_gain"] == 1.5
    assert table["last_third"]["frames"] == 0 and table["last_third"]["over_hold"] is None


def _per_task(own: list[float], hold: list[float], swap: list[float], frames: list[int] | None = None) -> list[dict]:
    """A :func:`ae.task_table` of made-up errors (mm), one task per value."""
    frames = frames or [4] * len(own)
    return [{"task": f"pseudo-s1-{index:06d}", "frames": count, "own_mm": o, "hold_mm": h, "swap_mm": w}
            for index, (o, h, w, count) in enumerate(zip(own, hold, swap, frames, strict=True))]


def _result(per_task: list[dict], seed: int = 0) -> dict:
    return {"seed": seed, "frames_per_task": 4, "horizon_T": 8, "per_task": per_task}


def test_task_intervals_on_known_cases():
    # two tasks of one frame each: a resample holds task 0 twice (1/4 of them), task 1 twice (1/4) or both, so the
    # percentiles are the ratios of each task alone
    two = ae.task_intervals(_per_task([1.0, 3.0], [2.0, 2.0], [2.0, 3.0], frames=[1, 1]))
    assert two["vs_holding_still"] == [0.5, 1.5] and two["context_gain_translation"] == [1.0, 2.0]
    # every task at the same ratios, whatever its size and frames: no spread, the interval is that ratio
    hold = [20.0, 30.0, 45.0, 25.0, 60.0, 35.0]
    own = [0.8 * h for h in hold]
    same = ae.task_intervals(_per_task(own, hold, [1.5 * o for o in own], frames=[4, 4, 3, 4, 2, 4]))
    assert same["vs_holding_still"] == [0.8, 0.8] and same["context_gain_translation"] == [1.5, 1.5]
    # tasks that differ a little give a narrow interval; one task ten times the others' size, far off their ratio,
    # pulls every resample that draws it: a much wider one
    spread = [0.78, 0.82, 0.8, 0.79, 0.81, 0.8]
    mild = ae.task_intervals(_per_task([r * 30 for r in spread], [30.0] * 6, [45.0] * 6))
    dominated_rows = _per_task([r * 30 for r in spread[:-1]] + [600.0], [30.0] * 5 + [300.0], [45.0] * 6)
    dominated = ae.task_intervals(dominated_rows)
    width = {name: interval["vs_holding_still"][1] - interval["vs_holding_still"][0]
             for name, interval in (("mild", mild), ("dominated", dominated))}
    assert 0 < width["mild"] < 0.05 and width["dominated"] > 10 * width["mild"]
    low, high = dominated["vs_holding_still"]
    assert low < (sum(r * 30 for r in spread[:-1]) + 600) / (5 * 30 + 300) < high
    # the seed fixes the draws: the same interval again, another seed another one; one task has none
    assert ae.task_intervals(dominated_rows) == dominated
    assert ae.task_intervals(dominated_rows, seed=1)["vs_holding_still"] != dominated["vs_holding_still"]
    assert (dominated["seed"], dominated["resamples"], dominated["clusters"]) == (ae.BOOTSTRAP_SEED, 10_000, 6)
    one = ae.task_intervals(_per_task([10.0], [20.0], [30.0]))
    assert one["vs_holding_still"] is None and one["context_gain_translation"] is None


def test_paired_ratio_difference_resamples_tasks_jointly_and_refuses_other_frames():
    hold = [20.0, 30.0, 45.0, 25.0, 60.0, 35.0]
    own = [16.0, 27.0, 30.0, 24.0, 39.0, 33.0]
    swap = [30.0, 33.0, 50.0, 26.0, 70.0, 40.0]
    a = _result(_per_task(own, hold, swap))
    itself = ae.paired_ratio_difference(a, a)
    for name in ae.RATIOS:
        assert itself[name]["difference"] == 0.0 and itself[name]["ci95"] == [0.0, 0.0]
        assert itself[name]["a"] == itself[name]["b"]
    # b 10% further from the actions on every task: its ratio over holding still is 1.1 times a's on every
    # resample, so the difference's interval is -0.1 times a's own interval (the same draws for both)
    b = _result(_per_task([1.1 * o for o in own], hold, [1.1 * w for w in swap]))
    paired = ae.paired_ratio_difference(a, b)
    ratio_a = sum(own) / sum(hold)
    assert paired["vs_holding_still"]["difference"] == pytest.approx(-0.1 * ratio_a, abs=1e-4)
    low, high = ae.task_intervals(a["per_task"])["vs_holding_still"]
    assert paired["vs_holding_still"]["ci95"] == pytest.approx([-0.1 * high, -0.1 * low], abs=2e-4)
    assert paired["context_gain_translation"]["difference"] == 0.0  # swap and own scaled alike
    assert (paired["unit"], paired["clusters"]) == ("task", 6)
    json.dumps(paired)
    # not the same frames: refused, saying why
    renamed = _result([{**row, "task": "pseudo-s2-000000"} if index == 0 else row
                       for index, row in enumerate(b["per_task"])])
    fewer_frames = _result([{**row, "frames": 3} if index == 2 else row for index, row in enumerate(b["per_task"])])
    other_hold = _result([{**row, "hold_mm": row["hold_mm"] + 1.0} for row in b["per_task"]])
    for other, message in ((_result(b["per_task"], seed=1), "differ in seed"),
                           ({**b, "frames_per_task": 2}, "differ in frames_per_task"),
                           (_result(b["per_task"][:5]), "different tasks"),
                           (renamed, "different tasks"),
                           (fewer_frames, "different tasks"),
                           (other_hold, "holding still's error on pseudo-s1-000000 differs"),
                           ({key: value for key, value in b.items() if key != "per_task"}, "lacks per_task")):
        with pytest.raises(ae.ActionErrorError, match=message):
            ae.paired_ratio_difference(a, other)


def test_a_policy_that_starts_from_the_replay_is_judged_beside_the_replay(held_out_root, monkeypatch):
    """With a replay strength every prediction (own and swapped) is handed the frame's replay prior, planned from
    the setting's N demonstrations; the result holds the replay's own errors per task and the ratio own / replay
    with its interval; a strength outside (0, 1] is refused before the weights load."""
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    predict, handed = InstantPolicyPolicy.predict_action_chunk, []
    monkeypatch.setattr(InstantPolicyPolicy, "predict_action_chunk",
                        lambda self, batch, **k: handed.append(k["initial_actions"]) or predict(self, batch, **k))
    result = _run(held_out_root, replay_init_strength=0.25, replay_per_object=True)
    assert result["replay_init_strength"] == 0.25 and result["replay_per_object"] is True
    tasks = ae.load_held_out_tasks(held_out_root, 2, 1, 8, seed=0)
    expected = [task.replay_priors(2, 8, "per_object")[0] for task in tasks]
    assert len(handed) == 4 and all(np.allclose(handed[i][0].numpy(), expected[i]) for i in range(2))
    assert not np.allclose(handed[2][0].numpy(), expected[0])  # the swap plans from the other task's demonstrations
    replay_mm = [row["replay_mm"] for row in result["per_task"]]
    pooled = sum(mm * row["frames"] for mm, row in zip(replay_mm, result["per_task"])) / result["frames"]
    assert pooled == pytest.approx(result["replay"]["translation_mm"], abs=0.01)
    own = result["settings"][0]["translation_mm"]
    # relative: on these one-layout tasks the replay is within a fraction of a millimetre, rounded to a micrometre
    assert result["intervals"]["vs_replay"]["value"] == pytest.approx(own / result["replay"]["translation_mm"],
                                                                      rel=5e-3)
    low, high = result["intervals"]["vs_replay"]["ci95"]
    assert low <= high
    assert all(isinstance(row["replay_wrong"], bool) for row in result["per_task"])  # each task's plan judged
    assert result["by_replay"]["right"]["tasks"] + result["by_replay"]["wrong"]["tasks"] == 2
    assert "replay" not in _run(held_out_root)  # the faithful path: no replay reference
    with pytest.raises(ae.ActionErrorError, match=r"replay_init_strength must lie in \(0, 1\]"):
        _run(held_out_root, replay_init_strength=1.5)


def test_tasks_whose_replay_is_right_and_wrong_are_reported_apart():
    """The split of a per-task table by its plans' wrongness: each group's ratios over its own tasks only (a
    corrector that keeps right starts, 1.0x the replay there, and halves wrong ones), one task too few for ratios."""
    rows = [{"task": f"t{i}", "frames": 2, "own_mm": own, "hold_mm": 20.0, "replay_mm": replay, "replay_wrong": wrong}
            for i, (own, replay, wrong) in enumerate([(5.0, 5.0, False), (6.0, 6.0, False), (4.0, 4.0, False),
                                                      (30.0, 60.0, True), (40.0, 80.0, True)])]
    split = ae.replay_split(rows)
    assert split["right"]["tasks"] == 3 and split["wrong"]["tasks"] == 2
    assert split["right"]["vs_replay"]["value"] == pytest.approx(1.0)
    assert split["right"]["vs_holding_still"]["value"] == pytest.approx(15.0 / 60.0)
    assert split["wrong"]["vs_replay"]["value"] == pytest.approx(0.5)
    assert split["wrong"]["replay_vs_holding_still"]["value"] == pytest.approx(140.0 / 40.0)
    assert ae.replay_split(rows[:4])["wrong"] == {"tasks": 1}
