"""``python -m workbench.cli.replay_error``: the replay plans' errors over demonstration-set folders as the suite
records them, each set's live scenes planned from the next set; bad input refused with exit status 2."""

from __future__ import annotations

import json

from synthetic_demos import carry_demo, object_pose

from lerobot_instant_policy.data.lerobot_format import create_dataset, write_episode
from workbench.cli.replay_error import main

SCENES = [(object_pose(0.45, 0.10, 0.0), object_pose(0.55, -0.12, 0.0)),
          (object_pose(0.50, 0.02, 30.0), object_pose(0.49, -0.20, -25.0))]


def write_sets(root) -> None:
    """Two sets of one carry demonstration each, in two scenes where the objects moved apart."""
    for index, scene in enumerate(SCENES):
        demo = carry_demo(*scene, seed=index)
        dataset = create_dataset("local/put_on_duck", root / f"put_on_duck-n1-s{100 * index}")
        write_episode(dataset, demo.points_world, demo.state, demo.action, demo.task)
        dataset.finalize()


def test_replay_error_reports_each_plan_per_task_and_pooled(tmp_path, capsys):
    write_sets(tmp_path)
    assert main([str(tmp_path), "--plans", "whole,anchored"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["tasks"] == {"put_on_duck": 2}
    anchored, whole = result["plans"]["anchored"], result["plans"]["whole"]
    assert anchored["all"]["gripper"]["count"] == 4  # two live scenes, a grasp and a release each
    assert anchored["per_task"]["put_on_duck"] == anchored["all"]
    assert anchored["all"]["gripper"]["translation_mm"]["p90"] < 6.0
    assert whole["all"]["gripper"]["translation_mm"]["p90"] > 30.0


def test_unknown_plans_and_folders_without_two_sets_are_refused(tmp_path, capsys):
    assert main([str(tmp_path), "--plans", "whole,segments"]) == 2
    assert "unknown plans ['segments']" in capsys.readouterr().err
    assert main([str(tmp_path)]) == 2
    assert "no task with two demonstration sets" in capsys.readouterr().err


def test_pseudo_tasks_are_measured_from_their_first_episode_onto_their_last(tmp_path, capsys):
    """``--pseudo-tasks``: one dataset whose episodes are grouped by task string; each task's last episode is the
    live scene, its first the context, as the stream plans a training prior. Asking for more tasks is refused."""
    dataset = create_dataset("local/pseudo", tmp_path / "pseudo")
    for task in ("pseudo-s1-000000", "pseudo-s1-000001"):
        for index, scene in enumerate(SCENES if task.endswith("0") else SCENES[::-1]):
            demo = carry_demo(*scene, seed=index)
            write_episode(dataset, demo.points_world, demo.state, demo.action, task)
    dataset.finalize()
    assert main([str(tmp_path / "pseudo"), "--pseudo-tasks", "2", "--plans", "whole,anchored"]) == 0
    result = json.loads(capsys.readouterr().out)
    anchored, whole = result["plans"]["anchored"]["all"], result["plans"]["whole"]["all"]
    assert anchored["gripper"]["count"] == 4 and anchored["missed_gripper_changes"] == 0
    assert anchored["gripper"]["translation_mm"]["p90"] < 6.0 < 30.0 < whole["gripper"]["translation_mm"]["p90"]
    assert main([str(tmp_path / "pseudo"), "--pseudo-tasks", "3"]) == 2
    assert "holds 2 pseudo-tasks" in capsys.readouterr().err


def test_within_a_set_each_episode_is_planned_from_the_others_of_its_own_set(tmp_path, capsys):
    """``--within-set``: one set of two episodes per task, as MetaWorld's dev split records; each episode is the live
    scene in turn, the other its context. A folder whose sets hold one episode each is refused."""
    dataset = create_dataset("local/put_on_duck", tmp_path / "one" / "put_on_duck-n2-s0")
    for index, scene in enumerate(SCENES):
        demo = carry_demo(*scene, seed=index)
        write_episode(dataset, demo.points_world, demo.state, demo.action, demo.task)
    dataset.finalize()
    assert main([str(tmp_path / "one"), "--plans", "whole,anchored"]) == 2  # one set: nothing to plan from
    capsys.readouterr()
    assert main([str(tmp_path / "one"), "--plans", "whole,anchored", "--within-set"]) == 0
    result = json.loads(capsys.readouterr().out)
    anchored, whole = result["plans"]["anchored"]["all"], result["plans"]["whole"]["all"]
    assert result["within_set"] and anchored["plans"] == 2
    assert anchored["gripper"]["translation_mm"]["p90"] < 6.0 < 30.0 < whole["gripper"]["translation_mm"]["p90"]
    write_sets(tmp_path / "single")
    assert main([str(tmp_path / "single"), "--within-set"]) == 2
    assert "no demonstration set of two episodes" in capsys.readouterr().err
