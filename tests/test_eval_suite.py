"""The evaluation path users run: record demonstrations, LeRobot's own lerobot-eval, the success table, make demo."""

import json
from pathlib import Path

import pytest

from lerobot_instant_policy.cli import demo, eval_suite


def test_lerobot_eval_command_names_task_policy_and_demos(tmp_path):
    command = eval_suite.lerobot_eval_command(
        "open_drawer", "demo_replay", None, tmp_path / "demos", 2, 10, 2, 1000, tmp_path / "run"
    )
    assert Path(command[0]).name == "lerobot-eval"
    assert "--env.task=open_drawer" in command and "--policy.type=demo_replay" in command
    assert f"--policy.demo_root={tmp_path / 'demos'}" in command and "--policy.num_demos=2" in command
    with_checkpoint = eval_suite.lerobot_eval_command(
        "open_drawer", "instant_policy", "ckpt/pretrained_model", tmp_path, 2, 10, 2, 1000, tmp_path / "run"
    )
    assert "--policy.path=ckpt/pretrained_model" in with_checkpoint
    assert not any(part.startswith("--policy.type") for part in with_checkpoint)


def test_policy_args_reach_lerobot_eval_and_runs_get_their_own_folder(tmp_path):
    args = eval_suite.build_parser().parse_args(
        ["--policy-arg", "inference_steps=8", "--policy-arg", "num_waypoints=5", "--run-name", "K8"]
    )
    assert args.policy_args == ["--policy.inference_steps=8", "--policy.num_waypoints=5"]
    command = eval_suite.lerobot_eval_command(
        "open_drawer", "demo_replay", None, tmp_path, 2, 10, 2, 1000, tmp_path / "run", policy_args=tuple(args.policy_args)
    )
    assert command[-2:] == ["--policy.inference_steps=8", "--policy.num_waypoints=5"]
    settings = eval_suite.SuiteSettings(out=tmp_path, run_name="K8")
    assert settings.runs_dir == tmp_path / "runs" / "K8"
    assert eval_suite.SuiteSettings(out=tmp_path).runs_dir == tmp_path / "runs" / "demo_replay"


@pytest.mark.parametrize("bad", ["inference_steps", "=8", "inference_steps=", "bad key=1"])
def test_malformed_policy_arg_is_refused(bad, capsys):
    with pytest.raises(SystemExit):
        eval_suite.build_parser().parse_args(["--policy-arg", bad])
    assert "KEY=VALUE" in capsys.readouterr().err


def test_run_name_must_be_a_plain_folder_name(capsys):
    with pytest.raises(SystemExit):
        eval_suite.main(["--run-name", "../escape", "--out", "unused"])
    assert "--run-name" in capsys.readouterr().err


def test_unknown_task_is_refused_with_the_known_ones(capsys):
    assert eval_suite.main(["--tasks", "open_drawer,fly_to_moon", "--out", "unused"]) == 2
    error = capsys.readouterr().err
    assert "fly_to_moon" in error and "open_drawer" in error and "push_button" in error


def test_best_policy_falls_back_to_demo_replay_without_a_checkpoint(tmp_path):
    policy, path, reason = demo.best_policy(tmp_path / "no_checkpoint")
    assert (policy, path) == ("demo_replay", None) and "no instant_policy checkpoint" in reason


def test_make_demo_runs_lerobot_eval_end_to_end(tmp_path, capsys):
    code = demo.main(
        [
            "--task",
            "push_button",
            "--episodes",
            "2",
            "--batch-size",
            "2",
            "--out",
            str(tmp_path),
            "--policy",
            "demo_replay",
        ]
    )
    output = capsys.readouterr().out
    assert code == 0, output
    info = json.loads(next(tmp_path.rglob("eval_info.json")).read_text())
    assert info["overall"]["n_episodes"] == 2
    assert [entry["task_group"] for entry in info["per_task"]] == ["push_button"]
    videos = info["overall"]["video_paths"]
    assert videos and all(Path(video).stat().st_size > 1000 for video in videos)
    assert "task push_button: demo_replay succeeded in" in output
    assert (tmp_path / "demos" / "push_button-n2-s0" / "meta" / "info.json").is_file()


@pytest.mark.slow
def test_eval_suite_writes_the_table_and_chart(tmp_path, capsys):
    assert eval_suite.main(["--tasks", "push_button,pick_and_lift", "--episodes", "2", "--out", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "success_table_demo_replay.json").read_text())
    assert {row["task"] for row in table["rows"]} == {"push_button", "pick_and_lift"}
    assert (tmp_path / "success_table_demo_replay.png").stat().st_size > 5000
