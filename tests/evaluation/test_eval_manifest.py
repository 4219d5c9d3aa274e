"""Columns joined only when comparable, and compared episode by episode: each suite cell records its seeds and
demonstration set, ``lerobot-ip-eval-table`` refuses columns whose seeds or demonstration sets differ, and the paired
difference with its cluster bootstrap interval on small known cases."""

from __future__ import annotations

import dataclasses
import json

import pytest

from lerobot_instant_policy.cli.eval_table import main as eval_table
from lerobot_instant_policy.evaluation import suite
from lerobot_instant_policy.evaluation.manifest import CELL_FILE, CellOutcome, ManifestError, column_manifest
from lerobot_instant_policy.evaluation.paired import paired_difference
from lerobot_instant_policy.evaluation.suite import SuiteSettings

TASKS = ["push_button", "open_drawer"]


@pytest.fixture
def fake_suite(monkeypatch):
    """``run_suite`` with lerobot-eval and the recorder replaced: each cell's episodes succeed as ``outcomes[policy
    name][(task, set)]`` says, each demonstration set is a file whose bytes name its source and seed."""
    outcomes: dict[str, dict[tuple[str, int], list[bool]]] = {}

    def fake_lerobot_eval(command, runs_dir, task, demo_set):
        output_dir = runs_dir / task / f"set-{demo_set}"
        output_dir.mkdir(parents=True, exist_ok=True)
        successes = outcomes[runs_dir.name][(task, demo_set)]
        info = {"per_task": [{"task_group": task, "task_id": 0, "metrics": {"successes": successes}}]}
        (output_dir / "eval_info.json").write_text(json.dumps(info))
        return output_dir

    def fake_record(settings, task, demos, seed, source):
        (demos / "data").mkdir(parents=True)
        (demos / "data" / "file.parquet").write_text(f"{source} {seed}")
        (demos / "meta").mkdir()
        (demos / "meta" / "info.json").write_text("{}")

    monkeypatch.setattr(suite, "run_lerobot_eval", fake_lerobot_eval)
    monkeypatch.setitem(suite.SUITE_ENVS, "bullet_tabletop",
                        dataclasses.replace(suite.SUITE_ENVS["bullet_tabletop"], record=fake_record))

    def run(settings: SuiteSettings, cells: dict[tuple[str, int], list[bool]]):
        outcomes[settings.name] = cells
        suite.run_suite(settings, TASKS, report=lambda line: None)
        return settings.runs_dir

    return run


def two_cells(first: list[bool], second: list[bool]) -> dict[tuple[str, int], list[bool]]:
    return {("push_button", 0): first, ("open_drawer", 0): second}


def test_cells_record_their_seeds_and_demonstrations(fake_suite, tmp_path):
    runs = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, split="test", demo_seed=50_000,
                                    eval_seed=60_000), two_cells([True, False], [False, False]))
    manifest = column_manifest(runs)
    cells = {(cell["task"], cell["demo_set"]): cell for cell in manifest["cells"]}
    assert cells[("push_button", 0)]["eval_seeds"] == [60_000, 60_001]
    assert cells[("push_button", 0)]["successes"] == [True, False]
    assert cells[("open_drawer", 0)]["demo_seed"] == 50_000 and len(cells[("open_drawer", 0)]["demo_fingerprint"]) == 64
    assert manifest["settings"]["policy"] == "demo_replay" and manifest["settings"]["success"] == "held"
    nothing = fake_suite(SuiteSettings(policy="do_nothing", out=tmp_path, episodes=2, demo_sets=1), two_cells(
        [False, False], [False, False]))
    assert {cell["demo_fingerprint"] for cell in column_manifest(nothing)["cells"]} == {None}


def test_table_joins_same_seeds_and_sets_and_refuses_others(fake_suite, tmp_path, capsys):
    replay = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1), two_cells([True, True], [True, False]))
    option = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, run_name="option"),
                        two_cells([True, True], [True, True]))
    swapped = fake_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, swap=True),
                         two_cells([False, False], [False, False]))
    out = tmp_path / "table"
    assert eval_table([f"demo_replay={replay}", f"option={option}", f"swap={swapped}", "--out", str(out),
                       "--paired", "option=demo_replay"]) == 0
    assert "option - demo_replay: +25.0 points" in capsys.readouterr().out
    manifests = json.loads(out.with_suffix(".manifest.json").read_text())
    assert set(manifests) == {"demo_replay", "option", "swap"}
    assert json.loads(out.with_suffix(".json").read_text())["paired"][0]["difference"] == 0.25

    other_seeds = fake_suite(SuiteSettings(out=tmp_path / "test", episodes=2, demo_sets=1, split="test",
                                           demo_seed=50_000, eval_seed=60_000), two_cells([True, True], [True, True]))
    assert eval_table([f"demo_replay={replay}", f"test={other_seeds}", "--out", str(out)]) == 2
    assert "different seeds" in capsys.readouterr().err
    other_demos = fake_suite(SuiteSettings(out=tmp_path / "other", episodes=2, demo_sets=1, demo_seed=500),
                             two_cells([True, True], [True, True]))
    assert eval_table([f"demo_replay={replay}", f"other={other_demos}", "--out", str(out)]) == 2
    assert "different demonstration sets" in capsys.readouterr().err


def test_runs_without_cell_records_need_unchecked(fake_suite, tmp_path, capsys):
    """A run from before cells recorded their identity is refused by name; ``--resume`` writes the record of the
    cells it keeps."""
    settings = SuiteSettings(out=tmp_path, episodes=2, demo_sets=1)
    runs = fake_suite(settings, two_cells([True, False], [False, False]))
    record_path = runs / "push_button" / "set-0" / CELL_FILE
    record = json.loads(record_path.read_text())
    identity = record.pop("cell")
    record_path.write_text(json.dumps(record))
    assert eval_table([f"demo_replay={runs}", "--out", str(tmp_path / "t")]) == 2
    assert "--unchecked" in capsys.readouterr().err
    assert eval_table([f"demo_replay={runs}", "--out", str(tmp_path / "t"), "--unchecked"]) == 0
    suite.run_suite(SuiteSettings(out=tmp_path, episodes=2, demo_sets=1, resume=True), TASKS, report=lambda l: None)
    assert json.loads(record_path.read_text())["cell"] == identity


def cell(task: str, successes: list[bool], seed: int = 1000) -> CellOutcome:
    return CellOutcome(task, 0, tuple(range(seed, seed + len(successes))), 0, 2, "f", None, tuple(successes))


def test_paired_difference_on_known_cases():
    """Two cells with differences 2/2 and 0/2: Δ = 0.5; the bootstrap draws each cell twice (Δ* = 1), once each
    (0.5) or the second twice (0), so its 95% interval is [0, 1]: no difference shown. When every cell favours A
    the interval lies above zero."""
    a = {("t1", 0): cell("t1", [True, True]), ("t2", 0): cell("t2", [True, False])}
    b = {("t1", 0): cell("t1", [False, False]), ("t2", 0): cell("t2", [True, False])}
    difference = paired_difference("a", a, "b", b)
    assert difference.difference == 0.5 and (difference.low, difference.high) == (0.0, 1.0)
    assert difference.verdict == "no difference shown" and difference.episodes == 4 and difference.cells == 2
    many_a = {(f"t{i}", 0): cell(f"t{i}", [True, True, False]) for i in range(8)}
    many_b = {(f"t{i}", 0): cell(f"t{i}", [True, False, False]) for i in range(8)}
    better = paired_difference("a", many_a, "b", many_b)
    assert better.low == better.high == pytest.approx(1 / 3) and better.verdict == "a beats b"
    assert paired_difference("b", many_b, "a", many_a).verdict == "a beats b"
    shifted = {key: cell(key[0], [True, True, False], seed=2000) for key in many_a}
    with pytest.raises(ManifestError, match="different seeds"):
        paired_difference("a", shifted, "b", many_b)
