"""``lerobot-ip-action-error``: the command line of :mod:`lerobot_instant_policy.evaluation.action_error` (offline
action error of an ``instant_policy`` checkpoint on held-out pseudo-tasks at one setting of K, N and L, with the
hold-still, untrained and context-swap references); prints JSON, and without ``--json`` a line after it on stderr
with the error over holding still's and the context gain, each with its 95% interval over tasks. The repository's
sweep over several settings is ``python -m workbench.cli.action_error_sweep`` in a clone."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable

from ..data.demonstrations import DemonstrationError
from ..evaluation.action_error import DEFAULT_K, DEFAULT_L, DEFAULT_N, ActionErrorError, action_error
from ..evaluation.checkpoints import EvaluationError

PROG = "lerobot-ip-action-error"


def _one_int(text: str) -> int:
    """One integer; a list (the sweep's ``1,2,4,8``) is refused with where the sweep lives."""
    try:
        return int(text)
    except ValueError as error:
        hint = " (several settings: python -m workbench.cli.action_error_sweep, in a clone)" if "," in text else ""
        raise argparse.ArgumentTypeError(f"expected one integer, got {text!r}{hint}") from error


def add_checkpoint_and_frames(parser: argparse.ArgumentParser) -> None:
    """The checkpoint, the held-out dataset and the frames read of it (the probe's and the workbench sweep's)."""
    parser.add_argument("--policy-path", required=True, help="a pretrained_model directory of instant_policy")
    parser.add_argument("--root", required=True, help="held-out pseudo-demonstration dataset (lerobot-ip-generate)")
    parser.add_argument("--repo-id", help="its repo id (default: local/<root name>)")
    parser.add_argument("--tasks", type=int, default=12, help="pseudo-tasks evaluated, the first ones (default 12)")
    parser.add_argument("--frames-per-task", type=int, default=4, help="frames of each live episode (default 4)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the frames and of the DDIM noise")


def add_prediction_and_output(parser: argparse.ArgumentParser) -> None:
    """How predictions are made and reported (the probe's and the workbench sweep's)."""
    parser.add_argument("--samples-per-prediction", type=int,
                        help="predict the mean of this many samples (the policy's samples_per_prediction; default: "
                             "the checkpoint's)")
    parser.add_argument("--no-untrained", action="store_true", help="skip the freshly initialised reference")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--json", action="store_true",
                        help="print JSON only (without it the JSON is followed, on stderr, by a line of the figures "
                             "with their intervals over tasks)")


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def _bracket(interval: list[float] | None) -> str:
    return "[-]" if interval is None else f"[{interval[0]:.3f}, {interval[1]:.3f}]"


def summary_line(result: dict) -> str:
    """The first setting of an action-error result (:func:`~..evaluation.action_error.action_error`, or the
    workbench sweep's) in one line: its translation error, the error over holding still's, the context gain in
    translation and, for a policy that starts from the replay, the error over the replay's, each ratio followed by its
    95% interval over tasks."""
    own, hold = result["settings"][0], result["hold"]["translation_mm"]
    intervals = result["intervals"]
    return (f"K={own['K']} N={own['N']} L={own['L']}, {result['tasks']} tasks x {result['frames_per_task']} frames: "
            f"{own['translation_mm']:.2f} mm, {_number(own['translation_mm'] / hold if hold > 0 else None)} x "
            f"holding still {_bracket(intervals['vs_holding_still'])}, context gain "
            f"{_number(result['context_gain']['translation'])} {_bracket(intervals['context_gain_translation'])}"
            + (f", {_number(intervals['vs_replay']['value'])} x the replay {_bracket(intervals['vs_replay']['ci95'])}"
               if "vs_replay" in intervals else "")
            + f" (95% intervals: cluster bootstrap over {intervals['clusters']} tasks)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description="Offline action error of an instant_policy checkpoint on held-out pseudo-tasks at one "
        "setting of K (denoising steps), N (demonstrations) and L (waypoints), against holding still and another "
        "task's demonstrations; prints JSON.")
    add_checkpoint_and_frames(parser)
    parser.add_argument("--K", type=_one_int, default=DEFAULT_K, help=f"denoising steps (default {DEFAULT_K})")
    parser.add_argument("--N", type=_one_int, default=DEFAULT_N, help=f"context demonstrations (default {DEFAULT_N})")
    parser.add_argument("--L", type=_one_int, default=DEFAULT_L,
                        help=f"waypoints per demonstration (default {DEFAULT_L})")
    parser.add_argument("--replay-init-strength", type=float,
                        help="start every prediction from the replay of the demonstrations noised to this strength "
                             "(the policy's replay_init_strength; default: the checkpoint's); the result then holds "
                             "the replay's own errors beside the policy's")
    parser.add_argument("--replay-per-object", choices=["true", "false"],
                        help="plan that replay per object (the policy's replay_per_object; default: the checkpoint's)")
    parser.add_argument("--replay-anchored", choices=["true", "false"],
                        help="plan that replay per segment, each following the object it approaches (the policy's "
                             "replay_anchored; default: the checkpoint's)")
    add_prediction_and_output(parser)
    return parser


def report(prog: str, compute: Callable[[], dict], json_only: bool) -> int:
    """Run ``compute`` (an action-error result, this command's or the workbench sweep's) and print it as JSON, and
    unless ``json_only`` :func:`summary_line` on stderr. Exit status: 2 where the inputs are refused, 1 where an
    error is not finite, else 0."""
    try:
        result = compute()
    except (ActionErrorError, EvaluationError, DemonstrationError, FileNotFoundError) as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    if not all(math.isfinite(v) for row in result["settings"] for v in row.values() if isinstance(v, float)):
        print(f"{prog}: error: non-finite errors {result['settings']}", file=sys.stderr)
        return 1
    print(json.dumps(result, indent=2))
    if not json_only:
        print(summary_line(result), file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return report(PROG, lambda: action_error(args.policy_path, args.root, args.tasks, args.frames_per_task, args.seed,
                                             args.K, args.N, args.L, not args.no_untrained, args.repo_id, args.device,
                                             args.samples_per_prediction, args.replay_init_strength,
                                             _switch(args.replay_per_object), _switch(args.replay_anchored)),
                  args.json)


def _switch(value: str | None) -> bool | None:
    """A ``true``/``false`` option's value, None where it was not given."""
    return None if value is None else value == "true"


if __name__ == "__main__":
    sys.exit(main())
