"""How much the network's internal state depends on the demonstrations, against how much it depends on the frame.

For a checkpoint and a held-out dataset, at φ's output (the current gripper nodes, the only way from the
demonstrations to the actions) and at ψ's output (the action nodes, at the first and the last denoising step):

    context share = mean ‖x(frame, own demos) − x(frame, next task's demos)‖ / mean ‖x(frame, own) − x(frame', own)‖

over the frames of ``lerobot-ip-action-error``'s held-out tasks (the same frames, demos and noise), where frame' is
another frame of the same task. A network that ignores its demonstrations scores 0; one whose state moves as much
with the demonstrations as with the observation scores about 1. Demonstrations differ in their scenes as well as in
their motion, so the script also reports

    task specificity = mean ‖x(own) − x(next task's demos)‖ / mean ‖x(own) − x(the same task's other demos)‖

which is about 1 when the state follows the demonstrations' scenes only, and above 1 when it tells tasks apart.

    python workbench/scripts/context_sensitivity.py CHECKPOINT_DIR HELD_OUT_ROOT [--tasks 24]
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
import torch

from lerobot_instant_policy.evaluation.action_error import load_held_out_tasks, predict_task, swapped_context
from lerobot_instant_policy.evaluation.checkpoints import load_policy


def captured_states(policy, tasks) -> dict[str, list[np.ndarray]]:
    """φ's current-node output and ψ's first action-node output, per frame, in task and frame order."""
    states: dict[str, list[np.ndarray]] = {"phi": [], "psi_first": [], "psi_last": []}
    calls = {"psi": 0}
    steps = policy.config.inference_steps

    def keep_phi(module, inputs, output):
        states["phi"].append(output["current"].detach().flatten().numpy().copy())

    def keep_psi(module, inputs, output):
        step = calls["psi"] % steps  # denoising step of the current prediction
        if step in (0, steps - 1):
            key = "psi_first" if step == 0 else "psi_last"
            states[key].append(output["action"].detach().flatten().numpy().copy())
        calls["psi"] += 1

    network = policy.network
    # the network runs φ and ψ in the dense layout, through forward_dense, which nn.Module hooks do not see
    handles = [_dense_hook(network.context_network, keep_phi), _dense_hook(network.action_network, keep_psi)]
    try:
        for held in tasks:
            policy.set_demonstrations(held.demos[:2], num_waypoints=10)
            predict_task(policy, held, policy.config.inference_steps, 2)
    finally:
        for handle in handles:
            handle.remove()
    return states


class _dense_hook:
    """A forward hook on ``forward_dense`` (which ``nn.Module`` hooks do not see)."""

    def __init__(self, module, hook):
        self.module, original = module, module.forward_dense

        def wrapped(*args, **kwargs):
            output = original(*args, **kwargs)
            hook(module, args, output)
            return output

        module.forward_dense = wrapped

    def remove(self):
        del self.module.forward_dense


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("root")
    parser.add_argument("--tasks", type=int, default=24)
    args = parser.parse_args()
    torch.manual_seed(0)
    policy = load_policy(args.checkpoint)
    tasks = load_held_out_tasks(args.root, args.tasks, 4, policy.config.horizon, 0, None)
    own = captured_states(policy, tasks)
    swap = captured_states(policy, swapped_context(tasks))
    # the same task's other demonstrations (demos 2 and 3 instead of 1 and 2): new scenes, the same motion
    resampled = captured_states(policy, [dataclasses.replace(held, demos=held.demos[1:]) for held in tasks])
    per_task = len(tasks[0].frames)
    result = {"checkpoint": args.checkpoint, "root": args.root, "frames": len(own["phi"])}
    for key in ("phi", "psi_first", "psi_last"):
        a, b, c = np.stack(own[key]), np.stack(swap[key]), np.stack(resampled[key])
        by_task = np.linalg.norm(a - b, axis=1).mean()
        by_demos = np.linalg.norm(a - c, axis=1).mean()
        # another frame of the same task, same demonstrations
        other = np.roll(a.reshape(len(tasks), per_task, -1), 1, axis=1).reshape(a.shape)
        by_frame = np.linalg.norm(a - other, axis=1).mean()
        result[f"{key}_context_share"] = round(float(by_task / by_frame), 4)
        result[f"{key}_task_specificity"] = round(float(by_task / by_demos), 4)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
