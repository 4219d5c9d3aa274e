"""How far apart are the motions of a task group's tasks over one action chunk? The context swap's ceiling.

``lerobot-ip-action-error``'s context swap hands a network the demonstrations of the *next* task, which on the ladder
is usually a task of the same object group (same two objects, its own anchor, pose and approach). A network that
imitated its demonstrations perfectly would, with the swapped ones, execute the other task's motion from the live
frame; its error is then the distance between the two tasks' action chunks from that frame. This script computes that
distance from the generator itself (no rendering, no network): for sampled frames of each task's reference path in a
fresh layout, the task's own chunk of T = 8 poses against the chunk the next task of its group would take from the
same pose in the same layout, next to holding still.

    ideal swap / hold ≈ 1 means a gain of 2 needs an own error of about 0.5× hold-still (the issue's other figure);
    ≪ 1 would make a gain of 2 unreachable for any network short of a perfect one.

    python workbench/scripts/swap_ceiling.py [--groups 12] [--seed 5]
"""

from __future__ import annotations

import argparse

import numpy as np

from lerobot_instant_policy.objects.library import load_object
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig
from lerobot_instant_policy.pseudo_demos.replay import DemoConfig, SceneLayout, reference_path, sample_layout
from lerobot_instant_policy.pseudo_demos.tasks import sample_pseudo_task

HORIZON = 8


def chunk(path: list[np.ndarray], frame: int) -> list[np.ndarray]:
    """The T poses after ``frame`` (the actions of a chunk), the last one repeated past the path's end."""
    return [path[min(frame + 1 + step, len(path) - 1)] for step in range(HORIZON)]


def angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R_a.T @ R_b) - 1.0) / 2.0, -1.0, 1.0))))


def ceiling(family: str, demo: DemoConfig, groups: int, group_size: int = 4, seed: int = 5, frames: int = 4,
            waypoint_max_roll_deg: float = 180.0) -> dict:
    """Mean translation (mm) and rotation (deg) over chunk steps and frames: hold-still and the ideal swap; and the
    median turn from the live EE to the path's end (what the network must register to read its demonstrations)."""
    pool = GenerationConfig(family=family, object_split="held_out").pool()
    hold_t, swap_t, hold_r, swap_r, to_goal = [], [], [], [], []
    for group in range(groups):
        group_rng = np.random.default_rng([seed, group, 1])
        objects = [load_object(pool[index]) for index in group_rng.choice(len(pool), 2, replace=False)]
        tasks = [sample_pseudo_task(f"g{group}-{k}", objects, np.random.default_rng([seed, group, k]), 0.5, family,
                                    waypoint_max_roll_deg) for k in range(group_size)]
        for k, task in enumerate(tasks):
            other = tasks[(k + 1) % group_size]
            rng = np.random.default_rng([seed, group, k, 7])
            layout = sample_layout(objects, rng, demo)
            path, _, _ = reference_path(task, layout)
            for frame in rng.choice(len(path), size=frames):
                current = path[frame]
                own = chunk(path, frame)
                other_path, _, _ = reference_path(other, SceneLayout(layout.T_world_objects, current))
                swapped = chunk(other_path, 0)
                hold_t.append(np.mean([np.linalg.norm(T[:3, 3] - current[:3, 3]) for T in own]))
                swap_t.append(np.mean([np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(own, swapped)]))
                hold_r.append(np.mean([angle_deg(T[:3, :3], current[:3, :3]) for T in own]))
                swap_r.append(np.mean([angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(own, swapped)]))
                to_goal.append(angle_deg(current[:3, :3], path[-1][:3, :3]))
    hold, swap = 1000 * float(np.mean(hold_t)), 1000 * float(np.mean(swap_t))
    return {"family": family, "hold_mm": round(hold, 1), "ideal_swap_mm": round(swap, 1),
            "ideal_swap_over_hold": round(swap / hold, 2), "hold_deg": round(float(np.mean(hold_r)), 1),
            "ideal_swap_deg": round(float(np.mean(swap_r)), 1), "turn_to_goal_median_deg": round(float(np.median(to_goal))),
            "turn_to_goal_over_90deg": round(float(np.mean(np.array(to_goal) > 90.0)), 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--groups", type=int, default=12)
    parser.add_argument("--seed", type=int, default=5)
    args = parser.parse_args()
    aligned = DemoConfig(object_max_yaw_deg=45.0, start_max_roll_deg=15.0)
    variants = {
        "reach": ("reach", DemoConfig(), 180.0),
        "reach, objects ±45°, start roll ±15°": ("reach", aligned, 180.0),
        "reach, objects ±45°, start roll ±15°, waypoint roll ±30° (rung1_reach_bounded)": ("reach", aligned, 30.0),
        "reach_grip": ("reach_grip", DemoConfig(), 180.0),
        "reach_grip, objects ±45°, start roll ±15°, waypoint roll ±30° (rung2_reach_grip_bounded)": (
            "reach_grip", aligned, 30.0),
        "grasp_place, bounded as above (rung3_grasp_place_shared_bounded)": ("grasp_place", aligned, 30.0),
        "full, bounded as above (rung4_full_shared_bounded)": ("full", aligned, 30.0),
    }
    for name, (family, demo, roll) in variants.items():
        print(name, ceiling(family, demo, args.groups, seed=args.seed, waypoint_max_roll_deg=roll))


if __name__ == "__main__":
    main()
