"""``python -m workbench.cli.hand_window`` (from the repository root): :mod:`workbench.hand_window`, printed as JSON."""

from __future__ import annotations

import argparse
import json
import sys

from ..hand_window import window_errors


def _ints(text: str) -> list[int]:
    """``0-5`` or ``1,3,5`` → a list of ints."""
    if "-" in text:
        first, last = (int(part) for part in text.split("-"))
        return list(range(first, last + 1))
    return [int(part) for part in text.split(",")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m workbench.cli.hand_window",
                                     description="The hand mapping's error against the simulated hand's truth, per "
                                     "landmark window, aperture window, gripper debounce and dwell.")
    parser.add_argument("--tasks", default="pick_and_lift,lift_lid,put_in_tray")
    parser.add_argument("--seeds", type=_ints, default=list(range(6)), help="dev seeds: 0-5 or 0,1,2")
    parser.add_argument("--windows", type=_ints, default=[1], help="landmark windows (odd)")
    parser.add_argument("--aperture-windows", type=_ints, default=[1, 3, 5, 7], help="aperture median windows (odd)")
    parser.add_argument("--holds", type=_ints, default=[1, 2, 3], help="gripper debounces (gripper_hold_frames)")
    parser.add_argument("--dwells", type=_ints, default=[1], help="frames held still from each gripper change")
    args = parser.parse_args(argv)
    print(json.dumps(window_errors(args.tasks.split(","), args.seeds, args.windows, args.aperture_windows, args.holds,
                                   args.dwells), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
