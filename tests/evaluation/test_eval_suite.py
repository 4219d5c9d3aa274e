"""The evaluation path users run: demonstration sets, LeRobot's own lerobot-eval, the success table, make demo."""

import dataclasses
import json
import sys
import types
from pathlib import Path

import av
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

from lerobot_instant_policy.cli import demo as demo_cli
from lerobot_instant_policy.cli import eval_suite
from lerobot_instant_policy.configuration_instant_policy import SHIPPED_CHECKPOINT, SHIPPED_REPLAY_PRIOR_CHECKPOINT
from lerobot_instant_policy.evaluation import demo, side_by_side, suite
from lerobot_instant_policy.evaluation.success_table import TASK_GROUPS, task_group
from lerobot_instant_policy.evaluation.suite import SuiteError, SuiteSettings


def test_lerobot_eval_command_names_task_policy_and_demos(tmp_path):
    settings = SuiteSettings(out=tmp_path)
    command = suite.lerobot_eval_command(settings, "open_drawer", tmp_path / "demos", 1000, tmp_path / "run")
    assert command[:3] == [sys.executable, "-m", suite.LEROBOT_EVAL]  # lerobot-eval, keeping each episode's seed
    assert "--env.task=open_drawer" in command and "--policy.type=demo_replay" in command
    assert f"--policy.demo_root={tmp_path / 'demos'}" in command and "--policy.num_demos=2" in command
    assert "--seed=1000" in command and "--eval.n_episodes=10" in command
    with_checkpoint = suite.lerobot_eval_command(
        SuiteSettings(policy="instant_policy", policy_path="ckpt/pretrained_model"), "open_drawer", tmp_path, 1000,
        tmp_path / "run",
    )
    assert "--policy.path=ckpt/pretrained_model" in with_checkpoint
    assert not any(part.startswith("--policy.type") for part in with_checkpoint)


def test_demonstration_sets_have_disjoint_seeds_and_the_same_scenes_for_every_policy(tmp_path):
    """Set s records from seed 100 s and evaluates its own 10 seeds; two policies get the same seeds; the swap reads
    the demonstrations of a task of the next group from their own folder."""
    settings = SuiteSettings(out=tmp_path, episodes=10, demo_sets=3)
    assert [settings.demo_seed_of(s) for s in range(3)] == [0, 100, 200]
    assert [settings.eval_seed_of(s) for s in range(3)] == [1000, 1010, 1020]
    other = SuiteSettings(policy="instant_policy", policy_path="ckpt", out=tmp_path, episodes=10, demo_sets=3)
    assert [other.eval_seed_of(s) for s in range(3)] == [settings.eval_seed_of(s) for s in range(3)]
    tasks = ["push_button", "pick_and_lift", "open_drawer", "close_drawer"]
    assert suite.swap_sources(tasks, task_group) == {"push_button": "open_drawer", "pick_and_lift": "close_drawer",
                                                     "open_drawer": "push_button", "close_drawer": "pick_and_lift"}
    own = suite.demo_root(tmp_path, "push_button", 2, 100)
    swapped = suite.demo_root(tmp_path, "push_button", 2, 100, source="pick_and_lift")
    assert own != swapped and swapped.name.endswith("-from-pick_and_lift")
    assert SuiteSettings(out=tmp_path, swap=True).runs_dir == tmp_path / "runs" / "demo_replay-swap"


def test_swap_reads_another_groups_task_on_every_task_of_the_suite():
    """On the whole suite every task reads the demonstrations of a task of another group (something else to do),
    each task's demonstrations are read once; within one group, the task half the list ahead."""
    tasks = sorted(task for group in TASK_GROUPS.values() for task in group)  # the built-in suite, as `all` orders it
    sources = suite.swap_sources(tasks, task_group)
    assert set(sources) == set(tasks) and sorted(sources.values()) == sorted(tasks)
    assert all(task_group(source) != task_group(task) for task, source in sources.items())
    assert sources["push_button"] != "pick_and_lift" and sources["open_drawer"] != "close_drawer"
    assert suite.swap_sources(["a", "b", "c", "d"], lambda task: "one") == {"a": "c", "b": "d", "c": "a", "d": "b"}
    with pytest.raises(SuiteError, match="at least two tasks"):
        suite.swap_sources(["a"], lambda task: "one")


@pytest.mark.parametrize(("overrides", "message"), [
    ({"demo_sets": 0}, "must be positive"),
    ({"policy": "instant_policy"}, "needs a policy_path"),
    ({"policy": "do_nothing", "swap": True}, "needs a policy that reads demonstrations or the task in words"),
    ({"demo_seed": 1000}, "overlap evaluation seeds"),
    ({"success": "eventually"}, "success must be one of"),
    ({"eval_seed": 250}, "overlap evaluation seeds"),
])
def test_bad_suite_settings_are_refused(tmp_path, overrides, message):
    with pytest.raises(SuiteError, match=message):
        SuiteSettings(out=tmp_path, **overrides).validate()


def test_policy_args_reach_lerobot_eval_and_runs_get_their_own_folder(tmp_path):
    args = eval_suite.build_parser().parse_args(
        ["--policy-arg", "inference_steps=8", "--policy-arg", "num_waypoints=5", "--run-name", "K8"]
    )
    assert args.policy_args == ["--policy.inference_steps=8", "--policy.num_waypoints=5"]
    settings = SuiteSettings(out=tmp_path, run_name="K8", policy_args=tuple(args.policy_args))
    command = suite.lerobot_eval_command(settings, "open_drawer", tmp_path, 1000, tmp_path / "run")
    assert command[-2:] == ["--policy.inference_steps=8", "--policy.num_waypoints=5"]
    assert settings.runs_dir == tmp_path / "runs" / "K8"
    assert SuiteSettings(out=tmp_path).runs_dir == tmp_path / "runs" / "demo_replay"


@pytest.mark.parametrize("bad", ["inference_steps", "=8", "inference_steps=", "bad key=1"])
def test_malformed_policy_arg_is_refused(bad, capsys):
    with pytest.raises(SystemExit):
        eval_suite.build_parser().parse_args(["--policy-arg", bad])
    assert "KEY=VALUE" in capsys.readouterr().err


def test_both_suite_commands_take_the_shared_arguments_and_their_envs_own():
    """``lerobot-ip-eval-suite`` and ``lerobot-ip-eval-metaworld`` parse the shared arguments alike
    (``evaluation.suite_command``) into settings of their env; each refuses the other env's own arguments."""
    from lerobot_instant_policy.cli import eval_metaworld
    from lerobot_instant_policy.evaluation import suite_command

    shared = ["--policy", "demo_replay", "--episodes", "4", "--split", "test", "--eval-seed", "70000", "--swap",
              "--policy-arg", "inference_steps=8", "--env-arg", "render_size=64", "--run-name", "K8", "--resume"]
    bullet = suite_command.suite_settings(eval_suite.build_parser().parse_args(shared), suite_command.BULLET_TABLETOP)
    metaworld = suite_command.suite_settings(eval_metaworld.build_parser().parse_args(shared), suite_command.METAWORLD)
    assert (bullet.env_type, metaworld.env_type) == ("bullet_tabletop", "metaworld_pointcloud")
    assert (bullet.demo_sets, metaworld.demo_sets) == (3, 1)  # each env's default
    assert dataclasses.replace(metaworld, env_type=bullet.env_type, demo_sets=3, out=bullet.out) == bullet
    assert (bullet.demo_seed, bullet.eval_seed, bullet.split) == (50_000, 70_000, "custom")
    with pytest.raises(SystemExit):
        eval_metaworld.build_parser().parse_args(["--obs-type", "rgbd"])
    with pytest.raises(SystemExit):
        eval_suite.build_parser().parse_args(["--episode-length", "100"])


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


def test_the_shipped_checkpoint_succeeds_on_the_demo_task_through_make_demo(tmp_path, capsys, monkeypatch):
    """``make demo``'s path on a fresh clone (its task, the two shipped checkpoints through ``--policy.path`` beside
    ``demo_replay``, each a real ``lerobot-eval`` process): given 2 demonstrations, the shipped checkpoint run from the
    replay prior (30/30 on the task's test split) closes the box (one episode, seed 1000), the table shows every
    column's episode as its ``lerobot-eval`` recorded it (the paper's inference, 12/30 there, may fail), and each
    column's test-split figure on the task is printed beside the episodes; the headline column failing every episode
    makes the demo exit with 1, a compared column's failure does not. Neither ``lerobot-eval`` prints a traceback, and the ``demo_replay`` one, which opens a LeRobot
    dataset and so probes LeRobot's video backend, says the probe's one line where no system FFmpeg is found (issue
    15: ``test_clean_output.py``)."""
    import subprocess

    from lerobot_instant_policy import video_backend

    assert demo.best_policy(SHIPPED_CHECKPOINT)[:2] == ("instant_policy", str(SHIPPED_CHECKPOINT))
    names = {str(SHIPPED_CHECKPOINT): "instant_policy", str(SHIPPED_REPLAY_PRIOR_CHECKPOINT): demo.REPLAY_PRIOR}
    outputs = {}

    def run_keeping_output(command, **kwargs):
        completed = subprocess.run(command, **kwargs)
        policy = next(arg.split("=", 1)[1] for arg in command if arg.startswith(("--policy.type=", "--policy.path=")))
        outputs[names.get(policy, policy)] = completed.stdout + completed.stderr
        return completed

    monkeypatch.setattr(suite, "subprocess", types.SimpleNamespace(run=run_keeping_output))
    code = demo_cli.main(["--episodes", "1", "--out", str(tmp_path)])
    captured = capsys.readouterr()
    assert code == 0, captured.out + captured.err
    assert f"policies: instant_policy, {demo.REPLAY_PRIOR}, demo_replay" in captured.out
    runs = {path.relative_to(tmp_path / "runs").parts[0]: json.loads(path.read_text())
            for path in tmp_path.rglob("eval_info.json")}
    assert set(runs) == {"instant_policy", demo.REPLAY_PRIOR, "demo_replay"} == set(outputs), sorted(runs)
    assert runs[demo.REPLAY_PRIOR]["per_task"][0]["metrics"]["successes"] == [True]
    successes = {name: runs[name]["per_task"][0]["metrics"]["successes"]
                 for name in ("instant_policy", demo.REPLAY_PRIOR, "demo_replay")}
    for name, success in successes.items():
        assert f"task {demo.DEFAULT_TASK}: {name} succeeded in {100 * success[0]:.0f}% of 1 episodes" in captured.out
    for info in runs.values():
        assert info["overall"]["n_episodes"] == 1
        assert [entry["task_group"] for entry in info["per_task"]] == [demo.DEFAULT_TASK]
        videos = info["overall"]["video_paths"]
        assert len(videos) == 1 and all(Path(video).stat().st_size > 1000 for video in videos)
    assert (tmp_path / "demos" / f"{demo.DEFAULT_TASK}-n2-s0" / "meta" / "info.json").is_file()
    for policy, output in outputs.items():
        assert "Traceback" not in output, f"{policy}'s lerobot-eval: {output[output.find('Traceback'):][:4000]}"
    if not video_backend.system_ffmpeg_found():
        assert video_backend.SHORT_MESSAGE in outputs["demo_replay"]  # the probe ran and said its one line
    # the side-by-side table: one row per episode with its seed and each policy's outcome
    rows = [line.split() for line in captured.out.splitlines() if line.split()[:1] in (["0"], ["1"])]
    assert rows == [["0", "1000"] + ["success" if success[0] else "fail" for success in successes.values()]]
    assert (f"test split on {demo.DEFAULT_TASK} ({demo.TEST_SPLIT_TABLE}: 3 demonstration sets x 10 episodes): "
            f"instant_policy 12/30, {demo.REPLAY_PRIOR} 30/30, demo_replay 15/30") in captured.out
    sheet = tmp_path / f"contact_sheet_{demo.DEFAULT_TASK}.png"
    assert f"contact sheet (first and last frame of every episode): {sheet}" in captured.out
    image = plt.imread(sheet)
    assert image.shape[0] > 200 and image.shape[1] > 300
    failing = [side_by_side.EpisodeOutcome(1000, False, None)]
    succeeding = [side_by_side.EpisodeOutcome(1000, True, None)]
    compared_failing = {"instant_policy": failing, demo.REPLAY_PRIOR: succeeding, "demo_replay": failing}
    assert demo.headline_failure(compared_failing) is None
    assert demo.headline_failure({**compared_failing, demo.REPLAY_PRIOR: failing}) == demo.REPLAY_PRIOR
    assert demo.headline_failure({"instant_policy": failing, "demo_replay": succeeding}) == "instant_policy"
    assert demo.headline_failure({"do_nothing": failing}) is None


def test_the_demo_reads_each_shipped_columns_test_split_figure_on_its_task(tmp_path):
    """From a success table's rows: the shipped checkpoints' and the baselines' columns on the task; a checkpoint of
    the user's own, a task the table lacks or a missing table give no figure."""
    table = tmp_path / "table.json"
    rows = [{"policy": "instant_policy", "task": "close_box", "successes": 12, "episodes": 30},
            {"policy": "ip_per_object_s0125_K8", "task": "close_box", "successes": 30, "episodes": 30},
            {"policy": "demo_replay", "task": "close_box", "successes": 15, "episodes": 30},
            {"policy": "demo_replay", "task": "pick_and_lift", "successes": 28, "episodes": 30}]
    table.write_text(json.dumps({"rows": rows}))
    policies, _ = demo.policies_to_run("auto", SHIPPED_CHECKPOINT, SHIPPED_REPLAY_PRIOR_CHECKPOINT)
    assert demo.test_split_figures("close_box", policies, table) == {
        "instant_policy": "12/30", demo.REPLAY_PRIOR: "30/30", "demo_replay": "15/30"}
    assert demo.test_split_figures("pick_and_lift", policies, table) == {"demo_replay": "28/30"}
    own = [demo.DemoPolicy("instant_policy", "instant_policy", str(tmp_path / "mine"))]
    assert demo.test_split_figures("close_box", own, table) == {}
    assert demo.test_split_figures("close_box", policies, tmp_path / "absent.json") == {}
    assert demo.TEST_SPLIT_TABLE.is_file()  # the checkout's table, which make demo reads


def test_auto_demo_runs_instant_policy_beside_demo_replay(tmp_path):
    policies, _ = demo.policies_to_run("auto", SHIPPED_CHECKPOINT, SHIPPED_REPLAY_PRIOR_CHECKPOINT)
    assert policies == [demo.DemoPolicy("instant_policy", "instant_policy", str(SHIPPED_CHECKPOINT)),
                        demo.DemoPolicy(demo.REPLAY_PRIOR, "instant_policy", str(SHIPPED_REPLAY_PRIOR_CHECKPOINT)),
                        demo.DemoPolicy("demo_replay", "demo_replay")]
    policies, reason = demo.policies_to_run("auto", tmp_path / "none", SHIPPED_REPLAY_PRIOR_CHECKPOINT)
    assert [column.name for column in policies] == [demo.REPLAY_PRIOR, "demo_replay"]
    assert f"instant_policy: no instant_policy checkpoint at {tmp_path / 'none'}" in reason
    policies, reason = demo.policies_to_run("auto", tmp_path / "none", tmp_path / "none")
    assert policies == [demo.DemoPolicy("demo_replay", "demo_replay")]
    assert demo.policies_to_run("do_nothing", SHIPPED_CHECKPOINT, SHIPPED_REPLAY_PRIOR_CHECKPOINT)[0] == [
        demo.DemoPolicy("do_nothing", "do_nothing")]
    assert demo.policies_to_run(demo.REPLAY_PRIOR, SHIPPED_CHECKPOINT, tmp_path / "mine")[0] == [
        demo.DemoPolicy(demo.REPLAY_PRIOR, "instant_policy", str(tmp_path / "mine"))]


def test_summary_table_and_outcomes_from_eval_info(tmp_path):
    info = {"per_task": [{"task_group": "push_button", "metrics": {"successes": [True, False]}}],
            "overall": {"video_paths": [str(tmp_path / "a.mp4"), str(tmp_path / "b.mp4")]}}
    (tmp_path / "eval_info.json").write_text(json.dumps(info))
    outcomes = side_by_side.episode_outcomes(tmp_path, 1000)
    assert [(e.seed, e.success, e.video.name) for e in outcomes] == [(1000, True, "a.mp4"), (1001, False, "b.mp4")]
    failing = [side_by_side.EpisodeOutcome(e.seed, False, None) for e in outcomes]
    table = side_by_side.summary_table("push_button", {"instant_policy": failing, "demo_replay": outcomes})
    lines = table.splitlines()
    assert lines[1].split() == ["episode", "seed", "instant_policy", "demo_replay"]
    assert lines[2].split() == ["0", "1000", "fail", "success"] and lines[3].split() == ["1", "1001", "fail", "fail"]
    assert lines[4].split() == ["success", "0%", "50%"]
    with pytest.raises(ValueError, match="different numbers of episodes"):
        side_by_side.summary_table("push_button", {"a": outcomes, "b": outcomes[:1]})
    with pytest.raises(FileNotFoundError, match="did lerobot-eval finish"):
        side_by_side.episode_outcomes(tmp_path / "missing", 1000)


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
    first, last = side_by_side.first_and_last_frames(tmp_path / "a.mp4")
    assert first.shape == (32, 32, 3) and first.dtype == np.uint8
    assert abs(int(first.mean()) - 20) < 8 and abs(int(last.mean()) - 240) < 8
    outcomes = {"demo_replay": [side_by_side.EpisodeOutcome(1000, True, tmp_path / "a.mp4")],
                "do_nothing": [side_by_side.EpisodeOutcome(1000, False, tmp_path / "a.mp4")]}
    image = plt.imread(side_by_side.draw_contact_sheet("push_button", outcomes, tmp_path / "sheet.png"))[..., :3]

    def share(colour: str) -> float:
        return float(np.all(np.abs(image - matplotlib.colors.to_rgb(colour)) < 0.03, axis=-1).mean())

    assert share(side_by_side.SUCCESS_COLOUR) > 0.002 and share(side_by_side.FAILURE_COLOUR) > 0.002
    outcomes["demo_replay"][0].success = False
    image = plt.imread(side_by_side.draw_contact_sheet("push_button", outcomes, tmp_path / "sheet.png"))[..., :3]
    assert share(side_by_side.SUCCESS_COLOUR) == 0.0


@pytest.mark.slow
def test_eval_suite_writes_the_table_and_chart_over_demonstration_sets_and_the_swap(tmp_path, capsys):
    """Two tasks × two demonstration sets × one episode: each set its own recorded demonstrations and lerobot-eval
    folder, pooled per task with a Wilson interval, grouped; the swap reads the other task's recording labelled as
    its own task."""
    assert eval_suite.main(["--tasks", "push_button,pick_and_lift", "--episodes", "1", "--demo-sets", "2",
                            "--out", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "success_table_demo_replay.json").read_text())
    rows = {row["task"]: row for row in table["rows"]}
    assert set(rows) == {"push_button", "pick_and_lift"} and all(row["episodes"] == 2 for row in rows.values())
    for row in rows.values():
        assert 0.0 <= row["ci95_low"] <= row["success_rate"] <= row["ci95_high"] <= 1.0
    assert [group["group"] for group in table["groups"]] == ["one object, one contact or grasp"]
    assert table["overall"]["demo_replay"]["episodes"] == 4
    for task in rows:
        for demo_set, seed in ((0, 0), (1, 100)):
            assert (tmp_path / "runs" / "demo_replay" / task / f"set-{demo_set}" / "eval_info.json").is_file()
            assert (tmp_path / "demos" / f"{task}-n2-s{seed}" / "meta" / "info.json").is_file()
    assert (tmp_path / "success_table_demo_replay.png").stat().st_size > 5000
    assert "overall (every episode)" in capsys.readouterr().out
    assert eval_suite.main(["--tasks", "push_button,pick_and_lift", "--episodes", "1", "--demo-sets", "1", "--swap",
                            "--out", str(tmp_path)]) == 0
    from lerobot.datasets import LeRobotDataset

    swapped = tmp_path / "demos" / "push_button-n2-s0-from-pick_and_lift"
    dataset = LeRobotDataset("local/push_button", root=swapped)
    assert list(dataset.meta.tasks.index) == ["push_button"]
    own = LeRobotDataset("local/push_button", root=tmp_path / "demos" / "push_button-n2-s0")
    assert dataset.meta.total_frames != own.meta.total_frames  # another task's motion, not this task's
    swap_table = json.loads((tmp_path / "success_table_demo_replay-swap.json").read_text())
    assert {row["policy"] for row in swap_table["rows"]} == {"demo_replay-swap"}


def test_resume_keeps_the_cells_evaluated_with_the_same_settings_and_refuses_other_settings(tmp_path, monkeypatch):
    """``--resume`` after an interrupted protocol: the finished cells are kept (a video size change is allowed: it
    changes no observation), the missing one is evaluated; other settings, another swap source, or finished cells
    without their settings record are refused before anything runs or is deleted. ``lerobot-eval`` is replaced by a
    stand-in writing its ``eval_info.json`` (the real call runs in make demo's test)."""
    evaluated = []

    def fake_lerobot_eval(command, runs_dir, task, demo_set):
        output_dir = runs_dir / task / f"set-{demo_set}"
        output_dir.mkdir(parents=True, exist_ok=True)
        (output_dir / "eval_info.json").write_text(json.dumps({"command": command}))
        evaluated.append((task, demo_set))
        return output_dir

    monkeypatch.setattr(suite, "run_lerobot_eval", fake_lerobot_eval)
    tasks = ["push_button", "knock_over"]
    settings = SuiteSettings(policy="do_nothing", out=tmp_path, episodes=2, demo_sets=2)
    suite.run_suite(settings, tasks, report=lambda line: None)
    assert evaluated == [("push_button", 0), ("push_button", 1), ("knock_over", 0), ("knock_over", 1)]
    (settings.runs_dir / "knock_over" / "set-1" / "eval_info.json").unlink()  # interrupted in the last cell

    evaluated.clear()
    lines = []
    resumed = SuiteSettings(policy="do_nothing", out=tmp_path, episodes=2, demo_sets=2, resume=True,
                            env_args=("--env.render_size=64",))
    runs = suite.run_suite(resumed, tasks, report=lines.append)
    assert evaluated == [("knock_over", 1)] and len(runs) == 4
    assert sum("kept from the earlier run" in line for line in lines) == 3

    for other, changed in ((dict(episodes=3), "episodes"), (dict(env_args=("--env.depth_noise_std=0.002",)), "env_args"),
                           (dict(eval_seed=2000), "eval_seed")):
        with pytest.raises(SuiteError, match=changed):
            suite.run_suite(dataclasses.replace(resumed, **other), tasks, report=lambda line: None)
    swapped = SuiteSettings(policy="demo_replay", out=tmp_path, episodes=2, demo_sets=1, swap=True)
    def fake_record(settings, task, demos, seed, source):
        (demos / "data").mkdir(parents=True)
        (demos / "data" / "episodes.parquet").write_text(f"{source} {seed}")

    monkeypatch.setitem(suite.SUITE_ENVS, "bullet_tabletop",
                        dataclasses.replace(suite.SUITE_ENVS["bullet_tabletop"], record=fake_record))
    suite.run_suite(swapped, tasks, report=lambda line: None)
    with pytest.raises(SuiteError, match="swap_source"):
        suite.run_suite(SuiteSettings(policy="demo_replay", out=tmp_path, episodes=2, demo_sets=1, swap=True,
                                      resume=True), [*tasks, "pick_and_lift"], report=lambda line: None)
    (settings.runs_dir / "push_button" / "set-0" / suite.CELL_FILE).unlink()
    evaluated.clear()
    with pytest.raises(SuiteError, match="no suite_cell.json"):
        suite.run_suite(resumed, tasks, report=lambda line: None)
    assert evaluated == [] and (settings.runs_dir / "push_button" / "set-0" / "eval_info.json").is_file()
