"""``lerobot-ip-eval-table``: the success table of suite runs, per task, per task group and overall, each rate with
its cluster 95% interval over tasks and its per-episode (Wilson) one, paired differences between columns, as text
or JSON on stdout and as OUT.json, OUT.png and OUT.manifest.json (``evaluation.success_table``,
``evaluation.manifest``, ``evaluation.paired``).

    lerobot-ip-eval-table instant_policy=outputs/eval_suite/runs/instant_policy demo_replay=outputs/eval_suite/runs/demo_replay \\
        --paired instant_policy=demo_replay
    lerobot-ip-eval-table docs/results_suite_test.manifest.json --allow-difference policy_options --out OUT
    lerobot-ip-eval-table instant_policy=RUN_DIR demo_replay=docs/results_suite_protocol.json --unchecked
    lerobot-ip-eval-table docs/results_suite_test.manifest.json \
        demo_replay=outputs/results/suite_test_slide_block/runs/demo_replay --allow-difference policy_options --out OUT

Columns come from suite run directories or from the manifest file of an earlier table (``[COLUMN=]FILE.manifest
.json``: every episode of each column, so its table can be derived again). They are joined only when their
manifests agree: the same cells (task × demonstration set), the same evaluation seeds, the same demonstration sets
where two columns read demonstrations of the same source, and the same conditions (``manifest.CONDITIONS``: the
checkpoint, policy options, success criterion, hold steps, step limit, env arguments, video size, …) unless
``--allow-difference NAME`` names one; otherwise the table is refused with the first difference. What a manifest
does not record (one written before the field was) is listed as not checked. ``--paired A=B`` prints A's success
rate minus B's over the same episodes, with a cluster bootstrap interval that resamples tasks (``--paired-unit
cell``: task × demonstration-set cells). ``--unchecked`` joins columns whose manifests are not known (an earlier
table's rows, runs from before cells recorded their seeds): no manifest, no paired difference.

A ``COLUMN=DIR`` after a manifest file that holds COLUMN amends that column (``manifest.amend_column``): the run's
cells (a task evaluated again) replace the column's cells of the same task × demonstration set, every other cell
stays, and the counts, intervals and paired differences are those of the amended column. The run may hold no cell
the column lacks, must have run each on the column's seeds, under its settings and conditions (but those named with
``--allow-difference``); demonstrations recorded again are noted. OUT.manifest.json names the replaced cells and
their run (``"replaced_cells"``). The manifest file comes first, then the runs that amend it.

``--recorded-differently`` prints the tasks (comma-separated, none: an empty line) where the columns read a
demonstration set of the same seeds recorded with other bytes, as pybullet on another machine may record it
(``manifest.recorded_differently``), and writes nothing: evaluate those tasks of the committed columns again here
and give the runs after the manifest file to amend them (``make results-candidate`` does).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..evaluation.manifest import (
    CONDITIONS,
    MANIFEST_SUFFIX,
    ManifestError,
    amend_column,
    cells_of,
    check_joinable,
    column_manifest,
    manifest_counts,
    read_manifest_file,
    recorded_differently,
)
from ..evaluation.paired import UNITS, paired_difference
from ..evaluation.success_table import (
    DEFAULT_ENV_TYPE,
    collect_results,
    format_table,
    is_table,
    path_argument,
    pool,
    results_json,
    write_table,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lerobot-ip-eval-table",
        description="Success table of suite runs with cluster (over tasks) and per-episode 95% intervals and paired "
                    "differences (text or JSON on stdout; JSON, PNG and manifest files).",
    )
    parser.add_argument("paths", nargs="+",
                        help="COLUMN=DIR: a suite run (OUT/runs/<name>) or lerobot-eval output dir; "
                             f"[COLUMN=]FILE{MANIFEST_SUFFIX}: the columns of an earlier table's manifest (a "
                             "COLUMN=DIR after a manifest that holds COLUMN replaces that column's cells of the run's "
                             "tasks); or [COLUMN=]TABLE.json: the rows of an earlier table (needs --unchecked)")
    parser.add_argument("--policy", default=None, help="column name for paths without a COLUMN= prefix")
    parser.add_argument("--env-type", default=DEFAULT_ENV_TYPE, help="env type lerobot-eval ran (default: %(default)s)")
    parser.add_argument("--out", default="eval_table", help="writes OUT.json, OUT.png and OUT.manifest.json")
    parser.add_argument("--paired", action="append", default=[], metavar="A=B",
                        help="print column A's success rate minus B's over the same episodes (repeatable)")
    parser.add_argument("--paired-unit", choices=UNITS, default="task",
                        help="what the paired differences' bootstrap resamples: tasks (default) or task x "
                             "demonstration-set cells")
    parser.add_argument("--bootstrap-seed", type=int, default=0,
                        help="seed of the paired differences' bootstrap (default: %(default)s)")
    parser.add_argument("--allow-difference", action="append", default=[], choices=list(CONDITIONS),
                        metavar="NAME", help="join columns that differ in this condition (repeatable): "
                                             f"{', '.join(CONDITIONS)}")
    parser.add_argument("--unchecked", action="store_true",
                        help="join columns without manifests (earlier tables, old runs): not checked, not paired")
    parser.add_argument("--json", action="store_true", help="print the table as JSON instead of text")
    parser.add_argument("--recorded-differently", action="store_true",
                        help="print the tasks whose demonstration sets the columns read recorded from the same seeds "
                             "with other bytes (comma-separated) and write nothing")
    return parser


def is_manifest_file(path: Path) -> bool:
    """Whether a PATH argument names an earlier table's ``OUT.manifest.json``."""
    return path.name.endswith(MANIFEST_SUFFIX)


def column_paths(paths: list[str], default_policy: str | None) -> dict[str, Path]:
    """``{column: run dir}`` of the ``[POLICY=]DIR`` arguments (earlier tables' ``.json`` are not run dirs)."""
    columns = {}
    for argument in paths:
        label, path = path_argument(argument)
        if not is_table(path):
            columns[label or default_policy or "policy"] = path
    return columns


def read_columns(paths: list[str], default_policy: str | None, env_type: str, unchecked: bool,
                 allowed: tuple[str, ...]):
    """The pooled counts of every PATH argument, the manifests of its columns (none with ``unchecked``, but those
    of manifest files, which are their columns' only record) and the notes of the manifest columns that run
    directories after them amend (``manifest.amend_column``, ``allowed``: the conditions they may differ in)."""
    file_manifests: dict[str, dict] = {}
    others = []
    notes = []
    for argument in paths:
        label, path = path_argument(argument)
        column = label or default_policy
        if is_manifest_file(path):
            if not path.is_file():
                raise FileNotFoundError(f"{path} does not exist")
            columns = read_manifest_file(path, label or None)
            before = sorted(set(columns) & set(column_paths(others, default_policy)))
            if before:
                raise ManifestError(f"{path} holds {', '.join(before)}, given before it as a run directory: put the "
                                    f"manifest file first for a run to replace that column's cells")
            file_manifests.update(columns)
        elif column in file_manifests and not is_table(path):
            file_manifests[column], column_notes = amend_column(column, file_manifests[column], path, allowed)
            notes += column_notes
        else:
            others.append(argument)
    counts = [count for name, manifest in file_manifests.items() for count in manifest_counts(name, manifest)]
    results = sorted(pool(collect_results(others, default_policy, env_type) + counts, lambda task: task),
                     key=lambda result: (result.task, result.policy))
    manifests = dict(file_manifests)
    if not unchecked:
        manifests.update({column: column_manifest(path) for column, path in column_paths(others, default_policy).items()})
    return results, manifests, notes


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    unknown: dict[str, list[str]] = {}
    try:
        pairs = [tuple(pair.split("=", 1)) for pair in args.paired]
        if any(len(pair) != 2 or not all(pair) for pair in pairs):
            raise ValueError(f"--paired takes A=B with two column names, got {args.paired}")
        results, manifests, notes = read_columns(args.paths, args.policy, args.env_type, args.unchecked,
                                                 tuple(args.allow_difference))
        if args.recorded_differently:
            if len(manifests) < 2:
                raise ManifestError("--recorded-differently compares the manifests of at least two columns")
            print(",".join(recorded_differently(manifests)))
            return 0
        if not args.unchecked:
            if len(manifests) < len({result.policy for result in results}):
                raise ManifestError("an earlier table's rows have no manifest: join them with --unchecked")
            unknown = check_joinable(manifests, tuple(args.allow_difference))
        differences = []
        for a, b in pairs:
            if a not in manifests or b not in manifests:
                raise ManifestError(f"--paired {a}={b}: both need a manifest (a suite run directory, not --unchecked)")
            differences.append(paired_difference(a, cells_of(manifests[a]), b, cells_of(manifests[b]),
                                                 seed=args.bootstrap_seed, unit=args.paired_unit))
    except (FileNotFoundError, ValueError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    out = Path(args.out)
    json_path, png_path = write_table(results, out, title=f"{args.env_type}: success per task")
    table = {**results_json(results), "paired": [difference.as_json() for difference in differences]}
    if manifests:
        table["allowed_differences"] = sorted(set(args.allow_difference))
        table["not_recorded"] = unknown
    json_path.write_text(json.dumps(table, indent=2) + "\n")
    written = [json_path, png_path]
    if manifests:
        written.append(out.with_suffix(".manifest.json"))
        written[-1].write_text(json.dumps(manifests, indent=2) + "\n")
    notes += [f"not recorded in {column}'s manifest, so not checked: {', '.join(names)}"
              for column, names in unknown.items()]
    for note in notes:
        print(f"{parser.prog}: note: {note}", file=sys.stderr)
    print(json.dumps(table) if args.json else "\n".join([format_table(results), *(d.line() for d in differences)]))
    if not args.json:
        print(f"\nwrote {', '.join(map(str, written))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
