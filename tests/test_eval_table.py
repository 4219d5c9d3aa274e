"""``lerobot-ip-eval-table``: the per-task success table over lerobot-eval output directories."""

from __future__ import annotations

import json

import pytest

from lerobot_instant_policy.cli.eval_table import main


def write_eval_info(run_dir, task_group: str, successes: list[bool]) -> None:
    """An ``eval_info.json`` laid out as ``lerobot_eval.eval_policy_all`` writes it (one task)."""
    metrics = {
        "sum_rewards": [float(s) for s in successes],
        "max_rewards": [float(s) for s in successes],
        "successes": successes,
        "video_paths": [str(run_dir / "videos" / f"{task_group}_0" / "eval_episode_0.mp4")],
        "predicted_video_paths": [],
    }
    rate = 100.0 * sum(successes) / len(successes)
    aggregate = {"avg_sum_reward": rate / 100, "avg_max_reward": rate / 100, "pc_success": rate, "n_episodes": len(successes)}
    info = {
        "per_task": [{"task_group": task_group, "task_id": 0, "metrics": metrics}],
        "per_group": {task_group: {**aggregate, "video_paths": metrics["video_paths"], "predicted_video_paths": []}},
        "overall": {**aggregate, "eval_s": 1.0, "eval_ep_s": 0.25, "video_paths": metrics["video_paths"], "predicted_video_paths": []},
    }
    run_dir.mkdir(parents=True)
    (run_dir / "eval_info.json").write_text(json.dumps(info, indent=2))


@pytest.fixture
def runs(tmp_path):
    """demo_replay on two tasks (one named only by its directory), instant_policy on one (two runs pooled)."""
    write_eval_info(tmp_path / "replay" / "lift", "pick_and_lift", [True, False, True, True])
    write_eval_info(tmp_path / "replay" / "open_drawer", "bullet_tabletop", [False, False, True, False])
    write_eval_info(tmp_path / "ip" / "a", "pick_and_lift", [True, True])
    write_eval_info(tmp_path / "ip" / "b", "pick_and_lift", [True, False])
    return tmp_path


def test_table_groups_policies_and_tasks(runs, tmp_path, capsys):
    out = tmp_path / "table" / "success"
    code = main([f"demo_replay={runs / 'replay'}", f"instant_policy={runs / 'ip'}", "--out", str(out), "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    rows = {(row["task"], row["policy"]): row for row in printed["rows"]}
    assert rows[("pick_and_lift", "demo_replay")]["episodes"] == 4
    assert rows[("pick_and_lift", "demo_replay")]["success_rate"] == pytest.approx(0.75)
    assert rows[("open_drawer", "demo_replay")]["success_rate"] == pytest.approx(0.25)
    assert rows[("pick_and_lift", "instant_policy")] == {
        "task": "pick_and_lift", "policy": "instant_policy", "episodes": 4, "successes": 3, "success_rate": 0.75,
    }
    assert printed["mean_success_rate"] == pytest.approx({"demo_replay": 0.5, "instant_policy": 0.75})
    assert json.loads(out.with_suffix(".json").read_text()) == printed
    png = out.with_suffix(".png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 5000


def test_text_table(runs, tmp_path, capsys):
    assert main([str(runs / "replay" / "lift"), str(runs / "replay" / "open_drawer"), "--policy", "demo_replay",
                 "--out", str(tmp_path / "t")]) == 0
    text = capsys.readouterr().out
    header, rule, *lines = text.splitlines()
    assert header.split() == ["task", "policy", "episodes", "success", "%"]
    assert set(rule) <= {"-", " "}
    assert lines[0].split() == ["open_drawer", "demo_replay", "4", "25.0"]
    assert lines[1].split() == ["pick_and_lift", "demo_replay", "4", "75.0"]
    assert lines[2].split() == ["mean", "over", "tasks", "demo_replay", "50.0"]


def test_policy_from_lerobot_eval_default_directory_name(tmp_path, capsys):
    write_eval_info(tmp_path / "outputs" / "eval" / "2026-01-01" / "12-00-00_bullet_tabletop_demo_replay", "push_button", [True])
    assert main([str(tmp_path / "outputs"), "--json", "--out", str(tmp_path / "t")]) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert (row["task"], row["policy"], row["success_rate"]) == ("push_button", "demo_replay", 1.0)


def test_bad_inputs_are_reported(tmp_path, capsys):
    assert main([str(tmp_path / "missing"), "--out", str(tmp_path / "t")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main([str(tmp_path / "empty"), "--out", str(tmp_path / "t")]) == 2
    assert "no eval_info.json" in capsys.readouterr().err
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "eval_info.json").write_text(json.dumps({"overall": {}}))
    assert main([str(tmp_path / "bad"), "--out", str(tmp_path / "t")]) == 2
    assert "no 'per_task' list" in capsys.readouterr().err
