"""The context-swap control's sources (``evaluation.suite.swap_sources``): a permutation of the tasks, every task
reading another group's demonstrations, on every task list the suites take; docs/metaworld.md's MT10 table equals
the code (new runs) and the committed manifest (the MT10 test-split swap that ran with the older pairing), and
docs/evaluation.md's suite pairings equal the code. No simulator, no MetaWorld import."""

from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

import pytest

from lerobot_instant_policy.evaluation import suite
from lerobot_instant_policy.evaluation.metaworld_suite import SWAP_GROUPS, swap_group
from lerobot_instant_policy.evaluation.success_table import TASK_GROUPS, task_group
from lerobot_instant_policy.sim.metaworld.configuration_metaworld import MT10_TASKS, task_groups

REPO = Path(__file__).resolve().parents[2]
METAWORLD_DOC = REPO / "docs" / "metaworld.md"
EVALUATION_DOC = REPO / "docs" / "evaluation.md"
MT10_TEST_MANIFEST = REPO / "docs" / "results_metaworld_mt10_test.manifest.json"
MT10_TEST_SWAP_RUNS = ("instant_policy-swap", "demo_replay-swap")


def assert_permutation(sources: dict[str, str], tasks: list[str]) -> None:
    """Every task has a source, every task is the source of exactly one task, and no task reads its own."""
    assert list(sources) == list(dict.fromkeys(tasks))
    assert sorted(sources.values()) == sorted(sources)
    assert all(task != source for task, source in sources.items())


def metaworld_task_lists() -> dict[str, list[str]]:
    """Every MetaWorld group ``lerobot-ip-eval-metaworld --tasks`` takes by name (mt10, mt50, ml45_train, ml45_test,
    LeRobot's difficulty groups)."""
    return task_groups()


@pytest.mark.parametrize("group", sorted(metaworld_task_lists()))
def test_metaworld_swap_is_a_permutation_of_another_kinds_tasks(group):
    """On every MetaWorld task list the suite takes (MT10, ML45's held-out tasks, the 50 tasks, ML45's training
    tasks, the difficulty groups) each task's demonstrations are read by exactly one other task, of another kind."""
    tasks = metaworld_task_lists()[group]
    sources = suite.swap_sources(tasks, swap_group)
    assert_permutation(sources, tasks)
    assert all(swap_group(task) != swap_group(source) for task, source in sources.items())
    assert suite.swap_sources(tasks, swap_group) == sources  # deterministic


def test_mt10_swap_reads_every_task_once_and_ml45_test_reads_the_next():
    """MT10: no source twice, none left out (the older pairing read door-open twice and peg-insert-side never);
    ML45's held-out tasks are kinds of their own, so each reads the next, the last the first."""
    mt10 = suite.swap_sources(list(MT10_TASKS), swap_group)
    assert Counter(mt10.values()) == Counter(MT10_TASKS)
    assert set(MT10_TASKS) == {task for tasks in SWAP_GROUPS.values() for task in tasks}
    ml45_test = task_groups()["ml45_test"]
    assert suite.swap_sources(ml45_test, swap_group) == dict(zip(ml45_test, ml45_test[1:] + ml45_test[:1]))


def test_bullet_suite_swap_is_the_next_groups_task_at_the_same_place():
    """The suite's 12 tasks (three groups of four, as ``all`` orders them): a permutation in which each task reads
    the task at its place in the next group, every group another's."""
    tasks = sorted(task for group in TASK_GROUPS.values() for task in group)
    sources = suite.swap_sources(tasks, task_group)
    assert_permutation(sources, tasks)
    groups: dict[str, list[str]] = {}
    for task in tasks:
        groups.setdefault(task_group(task), []).append(task)
    members = list(groups.values())
    assert [len(group) for group in members] == [4, 4, 4]
    assert sources == {task: members[(index + 1) % 3][place] for index, group in enumerate(members)
                       for place, task in enumerate(group)}


@pytest.mark.parametrize(("tasks", "groups"), [
    (["a1", "b1", "a2", "c1", "b2", "a3"], {"a": 3, "b": 2, "c": 1}),  # groups of unequal size, interleaved
    (["a1", "a2", "b1", "c1", "d1", "e1", "f1"], {"a": 2, "b": 1, "c": 1, "d": 1, "e": 1, "f": 1}),
    (["a1", "b1"], {"a": 1, "b": 1}),
])
def test_swap_permutes_groups_of_unequal_size_without_a_task_of_its_own_group(tasks, groups):
    """Wherever no group holds more than half the tasks, a permutation in which every task reads another group's."""
    sources = suite.swap_sources(tasks, lambda task: task[0])
    assert Counter(task[0] for task in tasks) == groups
    assert_permutation(sources, tasks)
    assert all(task[0] != source[0] for task, source in sources.items())


@pytest.mark.parametrize("tasks", [
    ["a1", "a2", "b1"], ["a1", "a2", "a3", "b1", "c1"], ["b1", "a1", "a2", "a3", "a4", "a5", "c1"],
])
def test_swap_with_a_majority_group_stays_a_permutation_and_crosses_groups_as_often_as_possible(tasks):
    """A group of more than half the tasks cannot read only other groups' demonstrations: still a permutation, no
    task reads its own, every task outside that group reads another group's, and so do as many of the group's own
    tasks as there are tasks outside it (the most any permutation allows)."""
    sources = suite.swap_sources(tasks, lambda task: task[0])
    assert_permutation(sources, tasks)
    outside = [task for task in tasks if task[0] != "a"]
    assert all(sources[task][0] == "a" for task in outside)
    assert sum(sources[task][0] != "a" for task in tasks if task[0] == "a") == len(outside)


def test_swap_within_one_group_reads_half_the_list_ahead_and_needs_two_distinct_tasks():
    assert suite.swap_sources(["a", "b", "c", "d"], lambda task: "one") == {"a": "c", "b": "d", "c": "a", "d": "b"}
    assert suite.swap_sources(["a", "b", "c"], lambda task: "one") == {"a": "b", "b": "c", "c": "a"}
    assert suite.swap_sources(["a", "b", "a"], lambda task: task) == {"a": "b", "b": "a"}
    for tasks in (["a"], ["a", "a"]):
        with pytest.raises(suite.SuiteError, match="at least two tasks"):
            suite.swap_sources(tasks, lambda task: "one")


def metaworld_doc_swap_table() -> list[tuple[str, str, str]]:
    """The rows of docs/metaworld.md's MT10 swap table: (task, its source now, its source in the committed run)."""
    text = METAWORLD_DOC.read_text()
    match = re.search(r"<!-- mt10-swap-table[^>]*-->\n(.*?)\n<!-- /mt10-swap-table -->", text, re.S)
    assert match, "docs/metaworld.md has no <!-- mt10-swap-table --> block"
    rows = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in match.group(1).splitlines()]
    assert len(rows[0]) == 3 and set(rows[1][0]) <= {"-"}  # the header and its rule
    return [tuple(row) for row in rows[2:]]


def test_metaworld_doc_swap_table_is_the_codes_pairing_and_the_committed_runs():
    """docs/metaworld.md's MT10 table: its middle column is what ``--swap`` runs now, its last column the source of
    every cell of the committed MT10 test-split swap columns, as their manifest records them (door-open's
    demonstrations read twice, peg-insert-side's never)."""
    rows = metaworld_doc_swap_table()
    assert [row[0] for row in rows] == list(MT10_TASKS)
    assert {task: now for task, now, _ in rows} == suite.swap_sources(list(MT10_TASKS), swap_group)
    committed = {task: then for task, _, then in rows}
    manifest = json.loads(MT10_TEST_MANIFEST.read_text())
    for run in MT10_TEST_SWAP_RUNS:
        cells = manifest[run]["cells"]
        assert {cell["task"] for cell in cells} == set(MT10_TASKS)
        assert {(cell["task"], cell["swap_source"]) for cell in cells} == set(committed.items()), run
    read = Counter(committed.values())
    assert read["door-open-v3"] == 2 and read["peg-insert-side-v3"] == 0
    assert [source for source, count in read.items() if count > 1] == ["door-open-v3"]
    assert set(MT10_TASKS) - set(read) == {"peg-insert-side-v3"}
    prose = " ".join(METAWORLD_DOC.read_text().split())
    assert "door-open's demonstrations were read twice" in prose and "peg-insert-side's never" in prose


def test_evaluation_doc_lists_the_suites_swap_pairings():
    """docs/evaluation.md's ``--swap`` item lists the suite's pairings (``A ← B``) as the code computes them."""
    text = " ".join(EVALUATION_DOC.read_text().split())
    item = text[text.index("`--swap`: the context-swap control"):]
    item = item[:item.index("(A ← B: A reads B's)")]
    listed = dict(re.findall(r"`(\w+) ← (\w+)`", item))
    tasks = sorted(task for group in TASK_GROUPS.values() for task in group)
    assert listed == suite.swap_sources(tasks, task_group)
