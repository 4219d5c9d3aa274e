"""Where the context stops helping: own error, hold-still and context gain split by the turn left to the goal.

On a reach pseudo-task (rung 1) the demonstrations end at the goal pose; to follow them from the live frame a network
must register the live view with the demonstrations' views. This script takes ``lerobot-ip-action-error``'s held-out
frames (the same tasks, frames, noise, K = 4, N = 2, L = 10), and splits them by

- ``turn_to_goal_deg``: the rotation angle between the live EE pose and the live episode's last pose (the goal);
- ``distance_to_goal_mm``: the distance between the two positions,

reporting per bin the own translation error, holding still, own / hold and the context gain (swap / own, the swap
handing over the next task's demonstrations). A gain that falls with the turn while it stays high for small turns
says what the network has not learned: registering views turned far from each other.

    python workbench/scripts/error_by_turn.py CHECKPOINT_DIR HELD_OUT_ROOT [--tasks 24]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from lerobot_instant_policy.data.demonstrations import open_demo_dataset, read_demonstration
from lerobot_instant_policy.evaluation.action_error import (
    chunk_errors,
    load_held_out_tasks,
    predict_task,
    swapped_context,
)
from lerobot_instant_policy.evaluation.checkpoints import load_policy

BINS = {"turn_to_goal_deg": [0, 30, 60, 90, 181], "distance_to_goal_mm": [0, 30, 80, 150, 2000]}


def frame_errors(policy, tasks) -> dict[tuple[str, int], float]:
    """Mean translation error (mm) over the chunk at every (task, frame) with each task's demonstrations."""
    errors = {}
    for held in tasks:
        policy.set_demonstrations(held.demos[:2], num_waypoints=10)
        for prediction, frame in zip(predict_task(policy, held, 4, 2), held.frames, strict=True):
            errors[held.task, frame.t] = float(chunk_errors(prediction, frame.target.astype(np.float64))
                                               ["translation_mm"].mean())
    return errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("root")
    parser.add_argument("--tasks", type=int, default=24)
    args = parser.parse_args()
    torch.manual_seed(0)
    policy = load_policy(args.checkpoint)
    tasks = load_held_out_tasks(args.root, args.tasks, 4, policy.config.horizon, 0)
    own, swap = frame_errors(policy, tasks), frame_errors(policy, swapped_context(tasks))
    dataset = open_demo_dataset(f"local/{Path(args.root).name}", Path(args.root))
    measures: dict[str, dict] = {name: {} for name in BINS}
    hold = {}
    for held in tasks:
        goal = read_demonstration(dataset, held.live_episode, held.task).state[-1]
        for frame in held.frames:
            key = held.task, frame.t
            turn = Rotation.from_quat(frame.state[3:7]).inv() * Rotation.from_quat(goal[3:7])
            measures["turn_to_goal_deg"][key] = float(np.degrees(turn.magnitude()))
            measures["distance_to_goal_mm"][key] = 1000.0 * float(np.linalg.norm(goal[:3] - frame.state[:3]))
            hold[key] = 1000.0 * float(np.linalg.norm(frame.target[:, :3] - frame.state[None, :3], axis=1).mean())
    for name, edges in BINS.items():
        for low, high in zip(edges[:-1], edges[1:], strict=True):
            keys = [key for key, value in measures[name].items() if low <= value < high]
            if not keys:
                continue
            own_mm, swap_mm, hold_mm = (float(np.mean([table[key] for key in keys])) for table in (own, swap, hold))
            print(json.dumps({"split": name, "bin": [low, high], "frames": len(keys), "own_mm": round(own_mm, 1),
                              "hold_mm": round(hold_mm, 1), "own_over_hold": round(own_mm / hold_mm, 2),
                              "context_gain": round(swap_mm / own_mm, 2)}))


if __name__ == "__main__":
    main()
