"""docs/test_runs.json, the ledger of every run on the held-out test split, against the committed tables: a table
whose columns were evaluated on the test split's seeds is named by a ledger entry, and a shipping decision rests on
runs the ledger holds."""

import json
from pathlib import Path

from lerobot_instant_policy.evaluation.suite import SEED_SPLITS

DOCS = Path(__file__).resolve().parents[2] / "docs"
LEDGER = json.loads((DOCS / "test_runs.json").read_text())


def ran_on_test_seeds(manifest: dict) -> bool:
    """Whether any column of a table's manifest (column → {"settings": ...}) ran on the test split's seeds."""
    demo_seed, eval_seed = SEED_SPLITS["test"]
    return any(column["settings"]["demo_seed"] == demo_seed and column["settings"]["eval_seed"] == eval_seed
               for column in manifest.values())


def test_every_committed_test_split_table_is_in_the_ledger():
    named = {figure.split(" ")[0] for run in LEDGER["runs"] for figure in run["figures"]}
    tables = sorted(path for path in DOCS.glob("*.manifest.json") if ran_on_test_seeds(json.loads(path.read_text())))
    assert tables, "no committed table ran on the test split's seeds: the check would pass on nothing"
    missing = [path.name for path in tables if f"docs/{path.name}" not in named]
    assert not missing, f"test-split tables that no docs/test_runs.json run names in its figures: {missing}"


def test_shipping_decisions_rest_on_runs_in_the_ledger():
    ids = [run["id"] for run in LEDGER["runs"]]
    assert len(ids) == len(set(ids)), "two ledger runs share an id"
    for decision in LEDGER["shipping_decisions"]:
        assert decision["rests_on"], decision
        assert set(decision["rests_on"]) <= set(ids), decision
