"""``lerobot-ip-demo`` (``make demo``): teach one ``bullet_tabletop`` task with 2 demonstrations and evaluate.

Records 2 scripted demonstrations of ``--task``, runs the best available policy for ``--episodes`` episodes
through ``lerobot-eval``, and prints the success rate and where the videos are. The best policy is
``instant_policy`` when a checkpoint is present (``--checkpoint``, default the one shipped in the package) and
the policy is installed, otherwise the classical ``demo_replay`` baseline.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .eval_suite import SuiteSettings, run_task

SHIPPED_CHECKPOINT = Path(__file__).resolve().parents[1] / "assets" / "checkpoints" / "instant_policy"
DEFAULT_TASK = "open_drawer"


def best_policy(checkpoint: Path) -> tuple[str, str | None, str]:
    """``(policy type, checkpoint or None, reason)``."""
    from lerobot.configs.policies import PreTrainedConfig

    if not (checkpoint / "config.json").is_file():
        return "demo_replay", None, f"no instant_policy checkpoint at {checkpoint}"
    if "instant_policy" not in PreTrainedConfig.get_known_choices():
        return "demo_replay", None, "the instant_policy policy is not installed in this version"
    return "instant_policy", str(checkpoint), f"checkpoint {checkpoint}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default=DEFAULT_TASK)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--batch-size", type=int, default=2)
    parser.add_argument("--checkpoint", type=Path, default=SHIPPED_CHECKPOINT, help="instant_policy pretrained_model")
    parser.add_argument(
        "--policy",
        choices=("auto", "demo_replay", "do_nothing"),
        default="auto",
        help="auto: instant_policy from --checkpoint when there is one, else demo_replay",
    )
    parser.add_argument("--out", type=Path, default=Path("outputs/demo"))
    args = parser.parse_args(argv)
    if args.policy == "auto":
        policy, policy_path, reason = best_policy(args.checkpoint)
    else:
        policy, policy_path, reason = args.policy, None, "--policy"
    print(f"policy: {policy} ({reason})", flush=True)
    settings = SuiteSettings(
        policy=policy, policy_path=policy_path, out=args.out, episodes=args.episodes, batch_size=args.batch_size
    )
    try:
        output_dir = run_task(settings, args.task)
    except (ValueError, RuntimeError) as error:
        print(f"lerobot-ip-demo: error: {error}", file=sys.stderr)
        return 2
    overall = json.loads((output_dir / "eval_info.json").read_text())["overall"]
    print(f"task {args.task}: {policy} succeeded in {overall['pc_success']:.0f}% of {overall['n_episodes']} episodes")
    print("videos:\n  " + "\n  ".join(overall.get("video_paths", [])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
