"""``python -m workbench.cli.action_error_sweep`` (from the repository root): the command line of
:mod:`workbench.action_error_sweep` (the offline action error of an ``instant_policy`` checkpoint on held-out
pseudo-tasks as K, N and L vary one at a time, with the hold-still, untrained and context-swap references at the
default setting); prints JSON, and without ``--json`` the default setting's line of ``lerobot-ip-action-error``
on stderr. One setting alone is the installed ``lerobot-ip-action-error``."""

from __future__ import annotations

import argparse
import sys

from lerobot_instant_policy.cli.action_error import add_checkpoint_and_frames, add_prediction_and_output, report
from lerobot_instant_policy.evaluation.action_error import DEFAULT_K, DEFAULT_L, DEFAULT_N

from ..action_error_sweep import DEFAULT_KS, DEFAULT_LS, DEFAULT_NS, action_error_sweep

PROG = "python -m workbench.cli.action_error_sweep"


def _int_list(text: str) -> list[int]:
    try:
        values = [int(part) for part in text.split(",") if part.strip()]
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from error
    if not values:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}")
    return values


def _listed(values: tuple[int, ...]) -> str:
    return ",".join(str(value) for value in values)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description="Offline action error of an instant_policy checkpoint on held-out pseudo-tasks, "
        "varying K (denoising steps), N (demonstrations) and L (waypoints) one at a time; prints JSON.")
    add_checkpoint_and_frames(parser)
    parser.add_argument("--K", type=_int_list, default=list(DEFAULT_KS),
                        help=f"denoising steps (default {_listed(DEFAULT_KS)})")
    parser.add_argument("--N", type=_int_list, default=list(DEFAULT_NS),
                        help=f"context demonstrations (default {_listed(DEFAULT_NS)})")
    parser.add_argument("--L", type=_int_list, default=list(DEFAULT_LS),
                        help=f"waypoints per demonstration (default {_listed(DEFAULT_LS)})")
    parser.add_argument("--default", type=_int_list, default=[DEFAULT_K, DEFAULT_N, DEFAULT_L],
                        help=f"the K,N,L held while another varies (default {DEFAULT_K},{DEFAULT_N},{DEFAULT_L})")
    add_prediction_and_output(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if len(args.default) != 3:
        print(f"{PROG}: error: --default takes K,N,L, got {args.default}", file=sys.stderr)
        return 2
    return report(PROG, lambda: action_error_sweep(args.policy_path, args.root, args.tasks, args.frames_per_task,
                                                   args.seed, args.K, args.N, args.L, tuple(args.default),
                                                   not args.no_untrained, args.repo_id, args.device,
                                                   args.samples_per_prediction), args.json)


if __name__ == "__main__":
    sys.exit(main())
