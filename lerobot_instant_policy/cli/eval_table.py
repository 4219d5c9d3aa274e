"""``lerobot-ip-eval-table``: the success table of ``lerobot-eval`` runs, per task, per task group and overall with
Wilson 95% intervals, as text or JSON on stdout and as OUT.json and OUT.png (``evaluation.success_table``).

    lerobot-ip-eval-table instant_policy=outputs/eval_suite/runs/instant_policy demo_replay=outputs/eval_suite/runs/demo_replay
    lerobot-ip-eval-table instant_policy=outputs/eval_suite/runs/instant_policy demo_replay=docs/results_suite_protocol.json

(the second reads ``demo_replay``'s rows of a table written earlier, e.g. on another machine).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..evaluation.success_table import DEFAULT_ENV_TYPE, collect_results, format_table, results_json, write_table


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lerobot-ip-eval-table",
        description="Success table of lerobot-eval runs with Wilson 95% intervals (text or JSON on stdout, JSON and "
                    "PNG files).",
    )
    parser.add_argument("paths", nargs="+",
                        help="[POLICY=]DIR: a lerobot-eval output dir or a parent of several; or [POLICY=]TABLE.json: "
                             "the rows of an earlier table (those of POLICY only, when given)")
    parser.add_argument("--policy", default=None, help="policy name for paths without a POLICY= prefix")
    parser.add_argument("--env-type", default=DEFAULT_ENV_TYPE, help="env type lerobot-eval ran (default: %(default)s)")
    parser.add_argument("--out", default="eval_table", help="writes OUT.json and OUT.png (default: %(default)s)")
    parser.add_argument("--json", action="store_true", help="print the table as JSON instead of text")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        results = collect_results(args.paths, args.policy, args.env_type)
    except (FileNotFoundError, ValueError) as error:
        print(f"lerobot-ip-eval-table: {error}", file=sys.stderr)
        return 2
    json_path, png_path = write_table(results, Path(args.out), title=f"{args.env_type}: success per task")
    print(json.dumps(results_json(results)) if args.json else format_table(results))
    if not args.json:
        print(f"\nwrote {json_path} and {png_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
