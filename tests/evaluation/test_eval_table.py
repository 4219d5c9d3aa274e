"""``lerobot-ip-eval-table``: the success table over lerobot-eval output directories, per task, per task group and
overall, each rate with its cluster bootstrap interval (over tasks; a task's row over its cells) and its per-episode
Wilson interval, both on known cases (these runs have no suite manifests: joined with ``--unchecked``; the manifest
checks and paired differences are tested in ``test_eval_manifest.py``)."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from lerobot_instant_policy.cli.eval_table import main
from lerobot_instant_policy.evaluation.success_table import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    SuccessCount,
    cluster_interval,
    pool,
    wilson_interval,
)


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
    code = main(["--unchecked", f"demo_replay={runs / 'replay'}", f"instant_policy={runs / 'ip'}", "--out", str(out), "--json"])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    rows = {(row["task"], row["policy"]): row for row in printed["rows"]}
    assert rows[("pick_and_lift", "demo_replay")]["episodes"] == 4
    assert rows[("pick_and_lift", "demo_replay")]["success_rate"] == pytest.approx(0.75)
    assert rows[("open_drawer", "demo_replay")]["success_rate"] == pytest.approx(0.25)
    low, high = wilson_interval(3, 4)
    assert rows[("pick_and_lift", "instant_policy")] == {
        "task": "pick_and_lift", "policy": "instant_policy", "episodes": 4, "successes": 3, "success_rate": 0.75,
        "cluster_ci95_low": 0.5, "cluster_ci95_high": 1.0, "cluster_unit": "cell", "clusters": 2,
        "ci95_low": low, "ci95_high": high,
    }  # its two runs (2/2 and 1/2) resampled: 1/2 and 2/2 drawn each over a quarter of the time
    assert rows[("pick_and_lift", "demo_replay")]["cluster_ci95_low"] is None  # one run: no cluster interval
    assert printed["overall"]["demo_replay"]["cluster_unit"] == "task"
    assert set(printed["intervals"]) == {"cluster_ci95", "ci95"}
    assert printed["mean_success_rate"] == pytest.approx({"demo_replay": 0.5, "instant_policy": 0.75})
    assert printed["overall"]["demo_replay"]["episodes"] == 8 and printed["overall"]["demo_replay"]["successes"] == 4
    groups = {(group["group"], group["policy"]): group for group in printed["groups"]}
    assert groups[("one object, one contact or grasp", "demo_replay")]["tasks"] == ["pick_and_lift"]
    assert groups[("articulated", "demo_replay")]["successes"] == 1
    assert json.loads(out.with_suffix(".json").read_text()) == printed
    png = out.with_suffix(".png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 5000


def test_text_table_groups_tasks_and_gives_intervals(runs, tmp_path, capsys):
    assert main(["--unchecked", str(runs / "replay" / "lift"), str(runs / "replay" / "open_drawer"), "--policy", "demo_replay",
                 "--out", str(tmp_path / "t")]) == 0
    header, rule, *lines = capsys.readouterr().out.splitlines()
    assert header.split() == ["task", "demo_replay"]
    assert set(rule) <= {"-", " "}
    assert lines[:5] == [line for line in lines[:5] if line.strip()]
    assert lines[0].split() == ["[one", "object,", "one", "contact", "or", "grasp]", "3/4", "75%", "[-]", "(30-95)"]
    assert lines[1].split() == ["pick_and_lift", "3/4", "75%", "[-]", "(30-95)"]
    assert lines[2].split() == ["[articulated]", "1/4", "25%", "[-]", "(5-70)"]
    assert lines[3].split() == ["open_drawer", "1/4", "25%", "[-]", "(5-70)"]
    assert lines[4].split() == ["overall", "(every", "episode)", "4/8", "50%", "[25-75]", "(22-78)"]
    assert "cluster bootstrap over tasks" in lines[6] and "Wilson interval per episode" in lines[6]


def test_wilson_interval_matches_the_closed_form_and_stays_inside_zero_one():
    """Wilson's score interval: (p + z²/2n ± z √(p(1−p)/n + z²/4n²)) / (1 + z²/n), z = 1.96 (95%)."""
    z = 1.959964
    for successes, episodes in ((0, 10), (3, 4), (10, 10), (21, 30)):
        p, n = successes / episodes, episodes
        centre, half = p + z * z / (2 * n), z * (p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5
        expected = ((centre - half) / (1 + z * z / n), (centre + half) / (1 + z * z / n))
        assert wilson_interval(successes, episodes) == pytest.approx(expected, abs=1e-6)
    assert wilson_interval(0, 10)[0] == pytest.approx(0.0, abs=1e-12) and wilson_interval(10, 10)[1] == pytest.approx(1.0)


def test_cluster_interval_on_a_hand_computable_case():
    """Two clusters, 1/2 and 0/2: a resample draws the first twice (rate 1/2, a quarter of the time), each once
    (1/4, half the time) or the second twice (0, a quarter): its 2.5th and 97.5th percentiles are 0 and 1/2. Fewer
    than two clusters give no interval; the same counts give the same interval."""
    assert cluster_interval([1, 0], [2, 2]) == (0.0, 0.5)
    assert cluster_interval([1, 0], [2, 2]) == cluster_interval([1, 0], [2, 2], seed=BOOTSTRAP_SEED)
    assert all(np.isnan(cluster_interval([3], [4]))) and all(np.isnan(cluster_interval([], [])))
    assert cluster_interval([2, 2, 2], [4, 4, 4]) == (0.5, 0.5)  # every task alike: zero width


def test_task_interval_resamples_tasks_as_a_direct_numpy_bootstrap_does():
    """A fixed table of 3 tasks × 2 cells: the overall row's interval is the percentile bootstrap over the tasks'
    pooled counts, computed here directly (same generator, one resample per row of draws), not over the 6 cells;
    and close to the exact bootstrap distribution (all 27 equally likely resamples of 3 tasks)."""
    cells = {"push_button": ((2, 10), (3, 10)), "open_drawer": ((9, 10), (10, 10)), "slide_block": ((0, 10), (6, 10))}
    counts = [SuccessCount(task, "p", 20, sum(s for s, _ in task_cells),
                           tuple((task, s, n) for s, n in task_cells)) for task, task_cells in cells.items()]
    (overall,) = pool(counts, lambda task: "overall")
    assert overall.cluster_unit == "task" and overall.cluster_count == 3 and overall.success_rate == 0.5
    per_task = np.array([[sum(s for s, _ in task_cells), sum(n for _, n in task_cells)] for task_cells in cells.values()])
    draws = np.random.default_rng(BOOTSTRAP_SEED).integers(0, 3, size=(BOOTSTRAP_RESAMPLES, 3))
    rates = np.array([per_task[row, 0].sum() / per_task[row, 1].sum() for row in draws])
    assert overall.cluster == tuple(np.percentile(rates, [2.5, 97.5]))
    exact = sorted(per_task[list(row), 0].sum() / 60 for row in itertools.product(range(3), repeat=3))
    assert overall.cluster == (exact[0], exact[-1])  # 1/27 of the mass at each end: beyond 2.5%
    by_cells = cluster_interval([s for task_cells in cells.values() for s, _ in task_cells], [10] * 6)
    assert by_cells[1] - by_cells[0] < overall.cluster[1] - overall.cluster[0]
    assert counts[0].cluster_unit == "cell" and counts[0].cluster == (0.2, 0.3)


def test_demonstration_sets_of_one_task_pool_under_the_task_name(tmp_path, capsys):
    """lerobot-ip-eval-suite writes runs/<policy>/<task>/set-<s>: sets named only by the env type pool per task."""
    for demo_set, successes in enumerate(([True, True], [False, True], [False, False])):
        write_eval_info(tmp_path / "runs" / "push_button" / f"set-{demo_set}", "bullet_tabletop", successes)
    assert main(["--unchecked", f"demo_replay={tmp_path / 'runs'}", "--json", "--out", str(tmp_path / "t")]) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert (row["task"], row["episodes"], row["successes"]) == ("push_button", 6, 3)


def test_metaworld_runs_group_by_mt10_kind(tmp_path, capsys):
    """MetaWorld runs (task named by its run directory) pool per MT10 kind, the swap control's groups; a task outside
    MT10 falls in ``other``."""
    for task, successes in (("door-open-v3", [True, False]), ("drawer-open-v3", [True, True]),
                            ("reach-v3", [False, False]), ("bin-picking-v3", [True, False])):
        write_eval_info(tmp_path / "runs" / task / "set-0", "metaworld_pointcloud", successes)
    assert main(["--unchecked", f"demo_replay={tmp_path / 'runs'}", "--env-type", "metaworld_pointcloud", "--json",
                 "--out", str(tmp_path / "t")]) == 0
    groups = {group["group"]: group for group in json.loads(capsys.readouterr().out)["groups"]}
    assert groups["MT10, open"]["tasks"] == ["door-open-v3", "drawer-open-v3"]
    assert (groups["MT10, open"]["episodes"], groups["MT10, open"]["successes"]) == (4, 3)
    assert groups["MT10, reach or move to a place"]["tasks"] == ["reach-v3"]
    assert groups["other"]["tasks"] == ["bin-picking-v3"]


def test_policy_from_lerobot_eval_default_directory_name(tmp_path, capsys):
    write_eval_info(tmp_path / "outputs" / "eval" / "2026-01-01" / "12-00-00_bullet_tabletop_demo_replay", "push_button", [True])
    assert main(["--unchecked", str(tmp_path / "outputs"), "--json", "--out", str(tmp_path / "t")]) == 0
    (row,) = json.loads(capsys.readouterr().out)["rows"]
    assert (row["task"], row["policy"], row["success_rate"]) == ("push_button", "demo_replay", 1.0)


def test_bad_inputs_are_reported(tmp_path, capsys):
    assert main(["--unchecked", str(tmp_path / "missing"), "--out", str(tmp_path / "t")]) == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["--unchecked", str(tmp_path / "empty"), "--out", str(tmp_path / "t")]) == 2
    assert "no eval_info.json" in capsys.readouterr().err
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "eval_info.json").write_text(json.dumps({"overall": {}}))
    assert main(["--unchecked", str(tmp_path / "bad"), "--out", str(tmp_path / "t")]) == 2
    assert "no 'per_task' list" in capsys.readouterr().err


def test_an_earlier_tables_rows_join_new_runs(runs, tmp_path, capsys):
    """``POLICY=TABLE.json`` reads that policy's rows of a table written earlier (elsewhere), pooled with new runs
    as if its runs were here; without a prefix every row under its own name; a file that is no table, or has no row
    of the policy, is refused."""
    earlier = tmp_path / "earlier"
    assert main(["--unchecked", f"demo_replay={runs / 'replay'}", f"instant_policy={runs / 'ip'}", "--out", str(earlier)]) == 0
    capsys.readouterr()
    write_eval_info(tmp_path / "new_ip", "open_drawer", [True, False])
    assert main(["--unchecked", f"demo_replay={earlier}.json", f"instant_policy={tmp_path / 'new_ip'}", "--out",
                 str(tmp_path / "joined"), "--json"]) == 0
    rows = {(row["task"], row["policy"]): row for row in json.loads(capsys.readouterr().out)["rows"]}
    assert set(rows) == {("pick_and_lift", "demo_replay"), ("open_drawer", "demo_replay"),
                         ("open_drawer", "instant_policy")}
    assert (rows[("pick_and_lift", "demo_replay")]["episodes"], rows[("pick_and_lift", "demo_replay")]["successes"]) == (4, 3)
    assert main(["--unchecked", f"{earlier}.json", "--out", str(tmp_path / "all"), "--json"]) == 0
    assert {row["policy"] for row in json.loads(capsys.readouterr().out)["rows"]} == {"demo_replay", "instant_policy"}
    assert main(["--unchecked", f"do_nothing={earlier}.json", "--out", str(tmp_path / "t")]) == 2
    assert "no rows of policy 'do_nothing'" in capsys.readouterr().err
    (tmp_path / "other.json").write_text(json.dumps({"per_task": []}))
    assert main(["--unchecked", str(tmp_path / "other.json"), "--out", str(tmp_path / "t")]) == 2
    assert "is not a success table" in capsys.readouterr().err
