"""The evaluation path users run: record demonstrations, LeRobot's own lerobot-eval, the success table, make demo."""

import json
from pathlib import Path

import av
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

from lerobot_instant_policy.cli import demo, demo_summary, eval_suite


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
    # the side-by-side table: one row per episode with its seed and outcome, then the rate
    successes = info["per_task"][0]["metrics"]["successes"]
    for index, success in enumerate(successes):
        assert f"{index:<7}  {1000 + index:<4}  {'success' if success else 'fail'}" in output
    sheet = tmp_path / "contact_sheet_push_button.png"
    assert f"contact sheet (first and last frame of every episode): {sheet}" in output
    image = plt.imread(sheet)
    assert image.shape[0] > 200 and image.shape[1] > 300


def test_auto_demo_runs_instant_policy_beside_demo_replay(tmp_path):
    policies, _ = demo.policies_to_run("auto", demo.SHIPPED_CHECKPOINT)
    assert policies == [("instant_policy", str(demo.SHIPPED_CHECKPOINT)), ("demo_replay", None)]
    policies, reason = demo.policies_to_run("auto", tmp_path / "no_checkpoint")
    assert policies == [("demo_replay", None)] and "no instant_policy checkpoint" in reason
    assert demo.policies_to_run("do_nothing", demo.SHIPPED_CHECKPOINT)[0] == [("do_nothing", None)]


def test_summary_table_and_outcomes_from_eval_info(tmp_path):
    info = {"per_task": [{"task_group": "push_button", "metrics": {"successes": [True, False]}}],
            "overall": {"video_paths": [str(tmp_path / "a.mp4"), str(tmp_path / "b.mp4")]}}
    (tmp_path / "eval_info.json").write_text(json.dumps(info))
    outcomes = demo_summary.episode_outcomes(tmp_path, 1000)
    assert [(e.seed, e.success, e.video.name) for e in outcomes] == [(1000, True, "a.mp4"), (1001, False, "b.mp4")]
    failing = [demo_summary.EpisodeOutcome(e.seed, False, None) for e in outcomes]
    table = demo_summary.summary_table("push_button", {"instant_policy": failing, "demo_replay": outcomes})
    lines = table.splitlines()
    assert lines[1].split() == ["episode", "seed", "instant_policy", "demo_replay"]
    assert lines[2].split() == ["0", "1000", "fail", "success"] and lines[3].split() == ["1", "1001", "fail", "fail"]
    assert lines[4].split() == ["success", "0%", "50%"]
    with pytest.raises(ValueError, match="different numbers of episodes"):
        demo_summary.summary_table("push_button", {"a": outcomes, "b": outcomes[:1]})
    with pytest.raises(FileNotFoundError, match="did lerobot-eval finish"):
        demo_summary.episode_outcomes(tmp_path / "missing", 1000)


def _write_video(path: Path, values: list[int]) -> None:
    """A 32×32 grey video whose frames have the given brightness values."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=10)
        stream.width, stream.height, stream.pix_fmt = 32, 32, "yuv420p"
        for value in values:
            frame = av.VideoFrame.from_ndarray(np.full((32, 32, 3), value, dtype=np.uint8), format="rgb24")
            container.mux(stream.encode(frame))
        container.mux(stream.encode())


def test_contact_sheet_shows_first_and_last_frames_framed_by_outcome(tmp_path):
    _write_video(tmp_path / "a.mp4", [20, 120, 240])
    first, last = demo_summary.first_and_last_frames(tmp_path / "a.mp4")
    assert first.shape == (32, 32, 3) and first.dtype == np.uint8
    assert abs(int(first.mean()) - 20) < 8 and abs(int(last.mean()) - 240) < 8
    outcomes = {"demo_replay": [demo_summary.EpisodeOutcome(1000, True, tmp_path / "a.mp4")],
                "do_nothing": [demo_summary.EpisodeOutcome(1000, False, tmp_path / "a.mp4")]}
    image = plt.imread(demo_summary.draw_contact_sheet("push_button", outcomes, tmp_path / "sheet.png"))[..., :3]

    def share(colour: str) -> float:
        return float(np.all(np.abs(image - matplotlib.colors.to_rgb(colour)) < 0.03, axis=-1).mean())

    assert share(demo_summary.SUCCESS_COLOUR) > 0.002 and share(demo_summary.FAILURE_COLOUR) > 0.002
    outcomes["demo_replay"][0].success = False
    image = plt.imread(demo_summary.draw_contact_sheet("push_button", outcomes, tmp_path / "sheet.png"))[..., :3]
    assert share(demo_summary.SUCCESS_COLOUR) == 0.0


@pytest.mark.slow
def test_eval_suite_writes_the_table_and_chart(tmp_path, capsys):
    assert eval_suite.main(["--tasks", "push_button,pick_and_lift", "--episodes", "2", "--out", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "success_table_demo_replay.json").read_text())
    assert {row["task"] for row in table["rows"]} == {"push_button", "pick_and_lift"}
    assert (tmp_path / "success_table_demo_replay.png").stat().st_size > 5000
