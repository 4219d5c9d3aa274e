"""How often a pseudo-demonstration dataset asks the policy to hold still: the share of 8-step action chunks that
contain a step without translation, the share of first actions that are exact holds (action position = state
position), and the share of frames whose observed gripper state differs from the commanded one (gripper faults).

Usage: python workbench/scripts/hold_statistics.py DATASET_ROOT REPO_ID   (prints JSON)
"""

import json
import sys

import numpy as np
from lerobot.datasets import LeRobotDataset

root, repo_id = sys.argv[1], sys.argv[2]
dataset = LeRobotDataset(repo_id, root=root)
frames = dataset.hf_dataset.with_format("numpy", columns=["observation.state", "action", "episode_index"])[:]
state, action, episode = frames["observation.state"], frames["action"], frames["episode_index"]
horizon, chunks_with_hold, chunks, first_holds, faults = 8, 0, 0, 0, 0
for index in np.unique(episode):
    rows = np.flatnonzero(episode == index)
    s, a = state[rows], action[rows]
    step = np.linalg.norm(a[:, :3] - s[:, :3], axis=1)  # the translation each action commands
    first_holds += int((step[:-1] < 1e-6).sum())  # the last frame's action holds by construction
    faults += int(((s[1:, 7] > 0.5) != (a[:-1, 7] > 0.5)).sum())
    for start in range(len(rows) - horizon):
        chunks += 1
        chunks_with_hold += bool((step[start:start + horizon] < 1e-6).any())
count = len(state) - len(np.unique(episode))
print(json.dumps({
    "dataset": root, "episodes": int(len(np.unique(episode))), "frames": int(len(state)),
    "chunks_with_a_hold_step": round(chunks_with_hold / chunks, 3),
    "first_action_is_a_hold": round(first_holds / count, 3),
    "frames_with_observed_gripper_unlike_command": round(faults / count, 3),
}, indent=2))
