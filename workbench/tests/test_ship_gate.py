"""The ship gate (``workbench.ship_gate``): the pooled difference is the per-task sum over every benchmark's tasks, a
candidate ships only when it is resolved better pooled and resolved worse on no benchmark, the committed tables of
the step-93,000 save give the recorded decision, and the ledger gains the decision only when it names known runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lerobot_instant_policy.evaluation.manifest import ManifestError
from workbench.cli.ship_gate import main
from workbench.ship_gate import ship_gate

DOCS = Path(__file__).resolve().parents[2] / "docs"


def column(successes_by_task: dict[str, list[int]]) -> dict:
    """A manifest column: one demonstration set per task, 10 episodes on seeds 0-9, ``successes`` per task."""
    return {"settings": {}, "cells": [
        {"task": task, "demo_set": 0, "eval_seeds": list(range(10)), "demo_seed": 1, "num_demos": 2,
         "demo_fingerprint": None, "swap_source": None, "successes": [bool(s) for s in successes]}
        for task, successes in successes_by_task.items()]}


def table(path: Path, candidate: dict[str, int], shipped: dict[str, int]) -> Path:
    """A joined table whose columns succeed in the first ``k`` of each task's 10 episodes."""
    manifests = {name: column({task: [1] * k + [0] * (10 - k) for task, k in counts.items()})
                 for name, counts in (("candidate", candidate), ("shipped", shipped))}
    path.write_text(json.dumps(manifests))
    return path


def test_pooled_difference_is_over_every_task_of_both_benchmarks(tmp_path):
    suite = table(tmp_path / "suite.manifest.json", {f"t{i}": 6 for i in range(6)}, {f"t{i}": 4 for i in range(6)})
    mt10 = table(tmp_path / "mt10.manifest.json", {f"t{i}": 5 for i in range(4)}, {f"t{i}": 5 for i in range(4)})
    decision = ship_gate("candidate", "shipped", [suite, mt10])
    # 6 tasks x +2 successes over 10 tasks x 10 episodes; the tasks of one name on both benchmarks stay apart
    assert decision.pooled.difference == pytest.approx(12 / 100)
    assert decision.pooled.clusters == 10
    assert decision.per_benchmark["suite"].difference == pytest.approx(0.2)
    assert decision.per_benchmark["mt10"].difference == 0
    assert decision.pooled.low > 0 and decision.ships


def test_resolved_worse_on_one_benchmark_does_not_ship(tmp_path):
    suite = table(tmp_path / "suite.manifest.json", {f"t{i}": 9 for i in range(12)}, {f"t{i}": 3 for i in range(12)})
    mt10 = table(tmp_path / "mt10.manifest.json", {f"t{i}": 4 for i in range(10)}, {f"t{i}": 6 for i in range(10)})
    decision = ship_gate("candidate", "shipped", [suite, mt10])
    assert decision.pooled.low > 0, "better pooled"
    assert decision.per_benchmark["mt10"].high < 0
    assert not decision.ships and "mt10" in decision.reason


def test_no_resolved_difference_does_not_ship(tmp_path):
    suite = table(tmp_path / "suite.manifest.json", {"a": 6, "b": 2}, {"a": 2, "b": 6})
    mt10 = table(tmp_path / "mt10.manifest.json", {"a": 5, "b": 5}, {"a": 5, "b": 5})
    decision = ship_gate("candidate", "shipped", [suite, mt10])
    assert decision.pooled.difference == 0 and not decision.ships
    assert decision.reason.startswith("no difference")


def test_the_step_93000_save_passes_the_gate_on_the_committed_tables():
    decision = ship_gate("standing_step93000", "instant_policy",
                         [DOCS / "results_suite_test_standing_step93000.manifest.json",
                          DOCS / "results_metaworld_mt10_test_standing_step93000.manifest.json"])
    assert decision.pooled.clusters == 22
    assert decision.pooled.difference == pytest.approx((30 + 47) / 660)  # 165 - 135 and 174 - 127 successes
    assert decision.ships


def test_bad_tables_are_refused(tmp_path):
    suite = table(tmp_path / "suite.manifest.json", {"a": 6}, {"a": 2})
    with pytest.raises(ValueError, match="at least two"):
        ship_gate("candidate", "shipped", [suite])
    with pytest.raises(ManifestError, match="no column 'other'"):
        ship_gate("other", "shipped", [suite, table(tmp_path / "mt10.manifest.json", {"a": 1}, {"a": 1})])
    fewer = table(tmp_path / "fewer.manifest.json", {"a": 6, "b": 1}, {"a": 2})
    with pytest.raises(ManifestError, match="same non-empty cells"):
        ship_gate("candidate", "shipped", [suite, fewer])
    same_name = tmp_path / "other" / "suite.manifest.json"
    same_name.parent.mkdir()
    with pytest.raises(ManifestError, match="two tables are named 'suite'"):
        ship_gate("candidate", "shipped", [suite, table(same_name, {"a": 1}, {"a": 1})])


def test_the_decision_is_recorded_only_when_it_names_runs_of_the_ledger(tmp_path, capsys):
    suite = table(tmp_path / "suite.manifest.json", {f"t{i}": 8 for i in range(6)}, {f"t{i}": 2 for i in range(6)})
    mt10 = table(tmp_path / "mt10.manifest.json", {f"t{i}": 5 for i in range(4)}, {f"t{i}": 5 for i in range(4)})
    ledger = tmp_path / "test_runs.json"
    ledger.write_text(json.dumps({"runs": [{"id": "suite-run"}, {"id": "mt10-run"}], "shipping_decisions": []}))
    before = ledger.read_text()
    args = ["candidate", "shipped", str(suite), str(mt10), "--record", str(ledger)]
    assert main([*args, "--rests-on", "suite-run", "unknown-run"]) == 2
    assert "unknown-run" in capsys.readouterr().err
    assert ledger.read_text() == before, "a refused decision leaves the ledger as it was"
    assert main([*args, "--rests-on", "suite-run", "mt10-run"]) == 0
    printed = json.loads(capsys.readouterr().out)
    decisions = json.loads(ledger.read_text())["shipping_decisions"]
    assert len(decisions) == 1 and decisions[0]["rests_on"] == ["suite-run", "mt10-run"]
    assert decisions[0]["gate"] == printed and printed["ships"]
    assert decisions[0]["decision"].startswith("candidate ships")
