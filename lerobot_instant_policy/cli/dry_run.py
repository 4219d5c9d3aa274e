"""``lerobot-ip-dry-run``: run a policy open-loop on a recorded episode and draw its predicted EE trajectory over
the point cloud, so that frames, units and the gripper mapping can be checked before the arm moves.

    lerobot-ip-dry-run --demos demos/converted --repo-id local/converted --episode 1 --out dry_run.png
    lerobot-ip-dry-run ... --policy-path CKPT/pretrained_model       (an instant_policy checkpoint)

The policy sees the recorded frames of ``--episode`` one after the other (clouds, EE states, the task) and its
demonstrations are ``--num-demos`` other episodes of the same task in the same dataset. The PNG shows the first
frame's cloud from above and from the side, the recorded EE path, the predicted EE path (circles where the
predicted gripper is closed) and the EE frame at the first frame (x red, y green, z blue: z must point along the
approach, into the objects for a top-down grasp). The printed summary gives the distance between the predicted
and the recorded path; nothing is sent to a robot. The dry run itself is
:mod:`lerobot_instant_policy.evaluation.dry_run`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..data.demonstrations import DemonstrationError
from ..evaluation.dry_run import draw_dry_run, dry_run, first_closed_step


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-dry-run", description=__doc__.split("\n\n")[0])
    parser.add_argument("--demos", type=Path, required=True, help="a dataset in the data contract (converted)")
    parser.add_argument("--repo-id", required=True)
    parser.add_argument("--episode", type=int, default=0, help="the recorded episode to run on")
    parser.add_argument("--num-demos", type=int, default=1, help="other episodes of its task used as demonstrations")
    parser.add_argument("--policy-path", help="a pretrained_model directory (default: the demo_replay baseline)")
    parser.add_argument("--out", type=Path, default=Path("outputs/dry_run.png"))
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        run = dry_run(args.demos, args.repo_id, args.episode, args.num_demos, args.policy_path)
    except (DemonstrationError, FileNotFoundError, ValueError) as error:
        print(f"lerobot-ip-dry-run: error: {error}", file=sys.stderr)
        return 2
    draw_dry_run(run, args.out)
    distance = run.position_error()
    predicted_close, recorded_close = first_closed_step(run.predicted), first_closed_step(run.recorded.action)
    print(
        f"{run.task}, episode {run.episode}, {run.recorded.num_frames} frames: predicted vs recorded EE position "
        f"{100 * distance.mean():.1f} cm mean, {100 * distance.max():.1f} cm max; gripper closes at predicted step "
        f"{'never' if predicted_close is None else predicted_close}, recorded "
        f"{'never' if recorded_close is None else recorded_close}; wrote {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
