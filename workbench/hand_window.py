"""How far the hand mapping's gripper is from the one the script commands, for each landmark window, aperture window,
gripper debounce and dwell: the measurement behind the conversion's ``window_frames``, ``aperture_window_frames`` and
``dwell_frames`` and the mapping's ``gripper_hold_frames`` and thresholds.

The simulated person (``sim.hand_demonstrator``) demonstrates a task on a seed; its recording holds the landmarks
with detector-like noise and dropped frames, and the demonstration its true EE frames and the script's gripper
command the hand follows (what the robot's gripper does in its own demonstration). Each setting maps the recording
(``perception.hand.map_hand_to_gripper`` with the simulator's mapping) and is compared frame by frame (dropped
frames bridged): the position and rotation errors against the true EE frames, over every frame and at the frames
where the mapped gripper changes (the poses a replay grasps and releases at), and the gripper against the command:
the share of frames that differ, the changes beyond the command's (a spurious open mid-carry drops the object, a
spurious close mid-air grasps nothing; negative: a grasp or release missed), and how many frames after the command
each change comes (the fingers take two or three frames to close).

``python -m workbench.cli.hand_window --tasks pick_and_lift,lift_lid,put_in_tray --seeds 0-3 --windows 1
--aperture-windows 1,3,5,7 --holds 1,2,3 --dwells 1,3,5``
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lerobot_instant_policy.geometry.se3 import rotation_angle
from lerobot_instant_policy.perception.hand import HandGapError, map_hand_to_gripper
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from lerobot_instant_policy.sim.hand_demonstrator import SIM_HAND_MAPPING, perform_hand_demonstration


def change_delays(mapped_open: np.ndarray, commanded_open: np.ndarray) -> list[int] | None:
    """Frames from each of the command's gripper changes to the mapped one (both ``(T,)``), or None when the two do
    not change the same number of times."""
    mapped, commanded = np.flatnonzero(np.diff(mapped_open)), np.flatnonzero(np.diff(commanded_open))
    return [int(m - c) for m, c in zip(mapped, commanded, strict=True)] if len(mapped) == len(commanded) else None


def window_errors(tasks: list[str], seeds: list[int], windows: list[int], aperture_windows: list[int],
                  holds: list[int], dwells: list[int] = (1,)) -> dict:
    """Per (landmark window, aperture window, debounce, dwell): the median and 90th percentile of the position (mm)
    and rotation (degrees) errors over every frame of every demonstration, their medians at the mapped changes, the
    share of frames whose gripper differs from the command, the changes beyond the command's per demonstration, the
    demonstrations whose changes match the command's in number and the median and largest delay of their changes
    (frames); demonstrations whose mapping refuses a gap are counted apart."""
    settings = [(w, a, k, d) for w in windows for a in aperture_windows for k in holds for d in dwells]
    records = {setting: {"position_mm": [], "rotation_deg": [], "changes": [], "wrong_gripper": [],
                         "extra_changes": [], "delays": [], "matched": 0, "gaps": 0} for setting in settings}
    demonstrations = 0
    for task in tasks:
        env = BulletTabletopEnv(task, BulletTabletopConfig(obs_type="rgbd", success="instant"))
        try:
            for seed in seeds:
                demonstration = perform_hand_demonstration(env, seed)
                demonstrations += 1
                commanded = demonstration.pinch_open.astype(np.float64)
                for window, aperture_window, hold, dwell in settings:
                    record = records[(window, aperture_window, hold, dwell)]
                    try:
                        mapping = replace(SIM_HAND_MAPPING, gripper_hold_frames=hold)
                        mapped = map_hand_to_gripper(demonstration.recording.landmarks_world, mapping,
                                                     window_frames=window, aperture_window_frames=aperture_window,
                                                     dwell_frames=dwell)
                    except HandGapError:
                        record["gaps"] += 1
                        continue
                    position = 1000 * np.linalg.norm(mapped.T_world_ee[:, :3, 3] - demonstration.T_world_ee[:, :3, 3],
                                                     axis=-1)
                    rotation = np.degrees(rotation_angle(demonstration.T_world_ee[:, :3, :3],
                                                         mapped.T_world_ee[:, :3, :3]))
                    record["position_mm"] += list(position)
                    record["rotation_deg"] += list(rotation)
                    changes = np.flatnonzero(np.diff(mapped.gripper_open)) + 1
                    record["changes"] += list(zip(position[changes], rotation[changes], strict=True))
                    record["wrong_gripper"] += list(mapped.gripper_open != commanded)
                    record["extra_changes"].append(int(np.abs(np.diff(mapped.gripper_open)).sum()
                                                       - np.abs(np.diff(commanded)).sum()))
                    delays = change_delays(mapped.gripper_open, commanded)
                    if delays is not None:
                        record["matched"] += 1
                        record["delays"] += delays
        finally:
            env.close()
    summary = {}
    for (window, aperture_window, hold, dwell), record in records.items():
        position, rotation = np.array(record["position_mm"]), np.array(record["rotation_deg"])
        delays, changes = np.array(record["delays"]), np.array(record["changes"]).reshape(-1, 2)
        summary[f"window={window},aperture_window={aperture_window},hold={hold},dwell={dwell}"] = {
            "position_mm_median": round(float(np.median(position)), 2),
            "position_mm_p90": round(float(np.percentile(position, 90)), 2),
            "rotation_deg_median": round(float(np.median(rotation)), 2),
            "rotation_deg_p90": round(float(np.percentile(rotation, 90)), 2),
            "position_mm_median_at_changes": round(float(np.median(changes[:, 0])), 2) if len(changes) else None,
            "rotation_deg_median_at_changes": round(float(np.median(changes[:, 1])), 2) if len(changes) else None,
            "wrong_gripper_frames": round(float(np.mean(record["wrong_gripper"])), 4),
            "extra_gripper_changes_per_demo": round(float(np.mean(record["extra_changes"])), 3),
            "demos_with_the_commands_changes": record["matched"],
            "change_delay_frames_median": float(np.median(delays)) if len(delays) else None,
            "change_delay_frames_max": int(delays.max()) if len(delays) else None,
            "refused_for_a_gap": record["gaps"],
        }
    return {"tasks": tasks, "seeds": seeds, "demonstrations": demonstrations, "settings": summary}
