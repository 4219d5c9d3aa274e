"""``lerobot-ip-eval-table``: the success table of suite runs, per task, per task group and overall with Wilson 95%
intervals, paired differences between columns, as text or JSON on stdout and as OUT.json, OUT.png and
OUT.manifest.json (``evaluation.success_table``, ``evaluation.manifest``, ``evaluation.paired``).

    lerobot-ip-eval-table instant_policy=outputs/eval_suite/runs/instant_policy demo_replay=outputs/eval_suite/runs/demo_replay \\
        --paired instant_policy=demo_replay
    lerobot-ip-eval-table instant_policy=RUN_DIR demo_replay=docs/results_suite_protocol.json --unchecked

Columns are joined only when their manifests agree: the same cells (task × demonstration set), the same evaluation
seeds, and the same demonstration sets where two columns read demonstrations of the same source; otherwise the
table is refused with the first difference. ``--paired A=B`` prints A's success rate minus B's over the same
episodes, with a cluster bootstrap interval over the cells. ``--unchecked`` joins columns whose manifests are not
known (an earlier table's rows, runs from before cells recorded their seeds): no manifest, no paired difference.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..evaluation.manifest import ManifestError, cells_of, check_joinable, column_manifest
from ..evaluation.paired import paired_difference
from ..evaluation.success_table import (
    DEFAULT_ENV_TYPE,
    collect_results,
    format_table,
    is_table,
    path_argument,
    results_json,
    write_table,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lerobot-ip-eval-table",
        description="Success table of suite runs with Wilson 95% intervals and paired differences (text or JSON on "
                    "stdout; JSON, PNG and manifest files).",
    )
    parser.add_argument("paths", nargs="+",
                        help="POLICY=DIR: a suite run (OUT/runs/<name>) or lerobot-eval output dir; or "
                             "[POLICY=]TABLE.json: the rows of an earlier table (needs --unchecked)")
    parser.add_argument("--policy", default=None, help="policy name for paths without a POLICY= prefix")
    parser.add_argument("--env-type", default=DEFAULT_ENV_TYPE, help="env type lerobot-eval ran (default: %(default)s)")
    parser.add_argument("--out", default="eval_table", help="writes OUT.json, OUT.png and OUT.manifest.json")
    parser.add_argument("--paired", action="append", default=[], metavar="A=B",
                        help="print column A's success rate minus B's over the same episodes (repeatable)")
    parser.add_argument("--unchecked", action="store_true",
                        help="join columns without manifests (earlier tables, old runs): not checked, not paired")
    parser.add_argument("--json", action="store_true", help="print the table as JSON instead of text")
    return parser


def column_paths(paths: list[str], default_policy: str | None) -> dict[str, Path]:
    """``{column: run dir}`` of the ``[POLICY=]DIR`` arguments (earlier tables' ``.json`` are not run dirs)."""
    columns = {}
    for argument in paths:
        label, path = path_argument(argument)
        if not is_table(path):
            columns[label or default_policy or "policy"] = path
    return columns


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        pairs = [tuple(pair.split("=", 1)) for pair in args.paired]
        if any(len(pair) != 2 or not all(pair) for pair in pairs):
            raise ValueError(f"--paired takes A=B with two column names, got {args.paired}")
        results = collect_results(args.paths, args.policy, args.env_type)
        manifests = {} if args.unchecked else {column: column_manifest(path)
                                                for column, path in column_paths(args.paths, args.policy).items()}
        if not args.unchecked:
            if len(manifests) < len({result.policy for result in results}):
                raise ManifestError("an earlier table's rows have no manifest: join them with --unchecked")
            check_joinable(manifests)
        differences = []
        for a, b in pairs:
            if a not in manifests or b not in manifests:
                raise ManifestError(f"--paired {a}={b}: both need a manifest (a suite run directory, not --unchecked)")
            differences.append(paired_difference(a, cells_of(manifests[a]), b, cells_of(manifests[b])))
    except (FileNotFoundError, ValueError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    out = Path(args.out)
    json_path, png_path = write_table(results, out, title=f"{args.env_type}: success per task")
    table = {**results_json(results), "paired": [difference.as_json() for difference in differences]}
    json_path.write_text(json.dumps(table, indent=2) + "\n")
    written = [json_path, png_path]
    if manifests:
        written.append(out.with_suffix(".manifest.json"))
        written[-1].write_text(json.dumps(manifests, indent=2) + "\n")
    print(json.dumps(table) if args.json else "\n".join([format_table(results), *(d.line() for d in differences)]))
    if not args.json:
        print(f"\nwrote {', '.join(map(str, written))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
