"""How far the hand mapping's gripper is from the simulated hand's true one, for each landmark window: the measurement
behind the conversion's ``window_frames``.

The simulated person (``sim.hand_demonstrator``) demonstrates a task on a seed; its recording holds the landmarks
with detector-like noise and dropped frames, and the demonstration its true EE frames and thumb-index apertures. Each
window w maps the recording (``perception.hand.map_hand_to_gripper`` with the simulator's mapping) and is compared
frame by frame with the truth (dropped frames bridged): the position error, the rotation error, and the
gripper: the frames whose state differs from the true aperture's under the same hysteresis, and the state changes
beyond the true ones (a spurious close mid-air makes a replay grasp nothing).

``python -m workbench.cli.hand_window --tasks pick_and_lift,lift_lid,put_in_tray --seeds 0-5 --windows 1,3,5,7,9``
"""

from __future__ import annotations

import numpy as np

from lerobot_instant_policy.geometry.se3 import rotation_angle
from lerobot_instant_policy.perception.hand import HandGapError, map_hand_to_gripper
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from lerobot_instant_policy.sim.hand_demonstrator import SIM_HAND_MAPPING, perform_hand_demonstration


def true_gripper(aperture: np.ndarray) -> np.ndarray:
    """The gripper state ``(T,)`` the simulator's hysteresis reads from the true apertures ``(T,)``."""
    state, states = 1.0, []
    for width in aperture:
        if width < SIM_HAND_MAPPING.close_below_m:
            state = 0.0
        elif width > SIM_HAND_MAPPING.open_above_m:
            state = 1.0
        states.append(state)
    return np.array(states)


def window_errors(tasks: list[str], seeds: list[int], windows: list[int]) -> dict:
    """Per window: the median and 90th percentile of the position (mm) and rotation (degrees) errors over every frame
    of every demonstration, the share of frames with the wrong gripper state and the spurious state changes per
    demonstration; demonstrations whose mapping refuses a gap are counted apart."""
    frames = {window: {"position_mm": [], "rotation_deg": [], "wrong_gripper": [], "extra_changes": [], "gaps": 0}
              for window in windows}
    demonstrations = 0
    for task in tasks:
        env = BulletTabletopEnv(task, BulletTabletopConfig(obs_type="rgbd", success="instant"))
        try:
            for seed in seeds:
                demonstration = perform_hand_demonstration(env, seed)
                demonstrations += 1
                truth = true_gripper(demonstration.aperture)
                recording = demonstration.recording
                for window in windows:
                    try:
                        mapped = map_hand_to_gripper(recording.landmarks_world, SIM_HAND_MAPPING,
                                                     window_frames=window)
                    except HandGapError:
                        frames[window]["gaps"] += 1
                        continue
                    record = frames[window]
                    record["position_mm"] += list(1000 * np.linalg.norm(
                        mapped.T_world_ee[:, :3, 3] - demonstration.T_world_ee[:, :3, 3], axis=-1))
                    record["rotation_deg"] += list(np.degrees(rotation_angle(
                        demonstration.T_world_ee[:, :3, :3], mapped.T_world_ee[:, :3, :3])))
                    record["wrong_gripper"] += list(mapped.gripper_open != truth)
                    record["extra_changes"].append(int(np.abs(np.diff(mapped.gripper_open)).sum()
                                                       - np.abs(np.diff(truth)).sum()))
        finally:
            env.close()
    summary = {}
    for window, record in frames.items():
        position, rotation = np.array(record["position_mm"]), np.array(record["rotation_deg"])
        summary[str(window)] = {
            "position_mm_median": round(float(np.median(position)), 2),
            "position_mm_p90": round(float(np.percentile(position, 90)), 2),
            "rotation_deg_median": round(float(np.median(rotation)), 2),
            "rotation_deg_p90": round(float(np.percentile(rotation, 90)), 2),
            "wrong_gripper_frames": round(float(np.mean(record["wrong_gripper"])), 4),
            "extra_gripper_changes_per_demo": round(float(np.mean(record["extra_changes"])), 3),
            "refused_for_a_gap": record["gaps"],
        }
    return {"tasks": tasks, "seeds": seeds, "demonstrations": demonstrations, "windows": summary}
