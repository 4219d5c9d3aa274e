"""Can the network follow a demonstration of the very scene it is in? The context with the live episode itself.

``lerobot-ip-action-error`` compares the task's own demonstrations (other scenes of the same motion) with another
task's. This script adds the easiest context there is: the live episode itself as one of the two demonstrations
(``self``: the live episode and the task's first other episode), so that one demonstration shows this very scene,
object layout included, and the motion to make from every point of it. Reading such a context needs no registration
of one layout onto another, only matching the current view with the demonstration waypoint that looks the same and
continuing from there. A network that reads its context at all should predict far better with it than with the
task's own demonstrations; one that ignores the context scores the same with all three.

Same held-out frames, noise and K, N = 2, L = 10 as ``lerobot-ip-action-error`` (24 tasks × 4 frames by default).

    python workbench/scripts/self_context.py CHECKPOINT_DIR HELD_OUT_ROOT [--tasks 24]
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import torch

from lerobot_instant_policy.data.demonstrations import open_demo_dataset, read_demonstration
from lerobot_instant_policy.evaluation.action_error import (
    evaluate_setting,
    hold_reference,
    load_held_out_tasks,
    swapped_context,
)
from lerobot_instant_policy.evaluation.checkpoints import load_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("root")
    parser.add_argument("--tasks", type=int, default=24)
    parser.add_argument("--frames-per-task", type=int, default=4)
    args = parser.parse_args()
    torch.manual_seed(0)
    policy = load_policy(args.checkpoint)
    tasks = load_held_out_tasks(args.root, args.tasks, args.frames_per_task, policy.config.horizon, 0, None)
    dataset = open_demo_dataset(f"local/{args.root.rstrip('/').split('/')[-1]}", args.root)
    own_scene = [
        dataclasses.replace(held, demos=[read_demonstration(dataset, held.live_episode, held.task), held.demos[0]])
        for held in tasks
    ]
    setting = (4, 2, 10)
    result = {"checkpoint": args.checkpoint, "hold": hold_reference(tasks)}
    for name, variant in (("own", tasks), ("self", own_scene), ("swap", swapped_context(tasks))):
        result[name] = evaluate_setting(policy, variant, setting)
    for name in ("self", "swap"):
        result[f"{name}_over_own_translation"] = round(
            result[name]["translation_mm"] / result["own"]["translation_mm"], 3)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
