"""Does φ's output move with the live frame, with the demonstrations, or with neither (a collapsed context path)?

For each checkpoint and held-out dataset given (pairs of arguments), at 4 evenly spaced frames of the live (last)
episode of each of the first 6 tasks, with the task's first two demonstrations and with the next task's (relabelled):

- ``spread``: the mean over features of their standard deviation across frames, over the mean magnitude, for σ's
  output at the current gripper nodes and for φ's (own and swapped demonstrations): about 0 for a network whose
  state is the same for every frame;
- ``swap / spread``: the mean change of φ's output when the demonstrations are swapped, over φ's spread across
  frames: about 0 for a network that ignores its demonstrations.

    python workbench/scripts/context_spread.py CHECKPOINT_DIR HELD_OUT_ROOT [CHECKPOINT_DIR HELD_OUT_ROOT ...]
"""

from __future__ import annotations

import json
import sys

import numpy as np
import torch
from goal_probe import read_tasks, task_features

from lerobot_instant_policy.evaluation.checkpoints import load_policy


def main() -> None:
    arguments = sys.argv[1:]
    if not arguments or len(arguments) % 2:
        raise SystemExit(__doc__)
    torch.set_num_threads(1)
    for checkpoint, root in zip(arguments[::2], arguments[1::2], strict=True):
        policy = load_policy(checkpoint)
        tasks = read_tasks(root, 6)
        features: dict[str, list[np.ndarray]] = {"sigma": [], "phi": [], "phi_swap": []}
        for index, (task, (first, second, live)) in enumerate(tasks):
            frames = np.linspace(0, live.num_frames - 1, 4).astype(int)
            swapped = list(tasks[(index + 1) % len(tasks)][1][:2])
            out = task_features(policy, task, [first, second], live, frames, swapped)
            for key in features:
                features[key].append(out[key])
        stacked = {key: np.concatenate(value) for key, value in features.items()}
        spread = {key: float(value.std(0).mean() / np.abs(value).mean()) for key, value in stacked.items()}
        swap = float(np.abs(stacked["phi"] - stacked["phi_swap"]).mean() / stacked["phi"].std(0).mean())
        print(json.dumps({"checkpoint": checkpoint, "spread": {key: round(value, 3) for key, value in spread.items()},
                          "phi_swap_over_spread": round(swap, 3)}))


if __name__ == "__main__":
    main()
