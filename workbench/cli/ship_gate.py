"""``python -m workbench.cli.ship_gate`` (from the repository root): the ship gate of :mod:`workbench.ship_gate` on
the joined test-split tables, printed as JSON; ``--record LEDGER --rests-on ID ...`` also appends the decision to the
ledger's ``shipping_decisions`` (docs/test_runs.json).

    python -m workbench.cli.ship_gate standing_best instant_policy \\
        docs/results_suite_test_standing_best.manifest.json docs/results_metaworld_mt10_test_standing_best.manifest.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
from pathlib import Path

from lerobot_instant_policy.evaluation.manifest import ManifestError

from ..ship_gate import ship_gate

PROG = "python -m workbench.cli.ship_gate"


def record(ledger: Path, decision: dict, rests_on: list[str]) -> None:
    """Append ``decision`` to ``ledger``'s ``shipping_decisions``, naming the runs it rests on, which must be in the
    ledger's ``runs``; the file is replaced whole, never left half-written."""
    entries = json.loads(ledger.read_text())
    known = {run["id"] for run in entries["runs"]}
    missing = [run for run in rests_on if run not in known]
    if not rests_on or missing:
        raise ValueError(f"--rests-on must name runs of {ledger}: {', '.join(missing) or 'none given'}")
    verdict = "ships" if decision["ships"] else "is not shipped"
    entries["shipping_decisions"].append({
        "date": datetime.date.today().isoformat(),
        "decision": f"{decision['candidate']} {verdict}: {decision['reason']} "
                    f"({100 * decision['pooled']['difference']:+.1f} points pooled)",
        "rests_on": rests_on, "gate": decision, "commit": None})
    partial = ledger.with_suffix(".json.partial")
    partial.write_text(json.dumps(entries, indent=2, ensure_ascii=False) + "\n")
    partial.replace(ledger)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description="Whether a candidate checkpoint ships: its paired "
                                     "difference from the shipped one on each benchmark's test split and pooled over "
                                     "all their tasks.")
    parser.add_argument("candidate", help="the candidate's column in each table")
    parser.add_argument("shipped", help="the shipped checkpoint's column in each table")
    parser.add_argument("tables", nargs="+", type=Path, help="joined tables (OUT.manifest.json), one per benchmark")
    parser.add_argument("--record", type=Path, metavar="LEDGER", help="append the decision to this ledger")
    parser.add_argument("--rests-on", nargs="+", default=[], metavar="ID", help="the ledger's runs it rests on")
    args = parser.parse_args(argv)
    try:
        decision = ship_gate(args.candidate, args.shipped, args.tables).as_json()
        if args.record:
            record(args.record, decision, args.rests_on)
    except (ManifestError, ValueError, FileNotFoundError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 2
    print(json.dumps(decision, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
