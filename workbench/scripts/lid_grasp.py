"""open_box: where the replay and a policy run from the replay prior take the lid's handle, and whether they keep it.

The suite's ``open_box`` is won by grasping the handle on the lid's free edge from above and swinging it about the
hinge beyond 0.9 rad. For each demonstration seed set, two scripted demonstrations are recorded in memory as the
recording does (``demo_end_margin.scripted_demonstrations``), their plan is made at each episode's first
observation (``replay.priors.plan_onto_live``) and executed by control step, then the policy runs on the same seed
from that plan. Per episode and runner, from the EE position expressed in the lid's link frame (``z`` along the
lid's outward normal, the fingers' direction when grasping from above):

- ``close_lag_mm``: how far the EE stands from the plan's pose at the step it first commands a close (the height it
  still has to descend, signed, then the distance), mm;
- ``grasp_z_mm``: the EE's height above the lid three steps after the close (the replay's grasp is ~33 mm: the
  handle's centre at 37.5 mm less the grasp depth);
- ``slip_mm``: how far the EE rises along the lid's normal while the gripper stays closed and before the lid reaches
  its largest angle, from where it held three steps after the close: the fingers drawn off the handle (a hand that
  keeps the handle moves with the lid);
- ``max_deg`` and ``end_deg``: the lid's largest and last angle; ``fell_back``: the last is 2° or more below the
  largest (the lid pushed back after it was opened).

Prints one JSON line per episode, then per runner the successes, the medians and the counts of episodes that
slipped (``slip_mm`` > 10) or fell back.

    python -m workbench.scripts.lid_grasp --demo-seeds 0,100,200 --seeds 1000-1009 --plan consensus \
        --policy-path lerobot_instant_policy/assets/checkpoints/instant_policy_replay_prior \
        [--policy-field n_action_steps=4]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from lerobot_instant_policy.replay.plan import REPLAY_PLANS
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from workbench.replay_episodes import episode_action, replay_policy, seed_list, start_episode
from workbench.scripts.demo_end_margin import scripted_demonstrations

TASK = "open_box"
SLIPPED_MM = 10.0  # fingers drawn this far off the handle have lost it
FELL_BACK_DEG = 2.0


def run(env: BulletTabletopEnv, demonstrations, plan_name: str, seed: int, policy=None) -> dict:
    """One episode of ``seed``: the plan executed by control step (``policy`` None) or ``policy`` from it."""
    observation, plan = start_episode(env, TASK, demonstrations, plan_name, seed, policy)
    ee_lid, angle, closed, lag, info = [], [], [], None, {}
    for step in range(env._max_episode_steps):
        action = episode_action(policy, plan, step, observation, TASK)
        T_world_lid = env.task_impl._lid_frame(env.scene)
        ee = observation["agent_pos"][:3]
        ee_lid.append(T_world_lid[:3, :3].T @ (ee - T_world_lid[:3, 3]))
        angle.append(np.degrees(env.task_impl.angle(env.scene)))
        closed.append(bool(action[7] < 0.5))
        if closed[-1] and lag is None:
            planned = plan[min(step, len(plan) - 1), :3]
            lag = [float(ee[2] - planned[2]) * 1e3, float(np.linalg.norm(ee - planned)) * 1e3]
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    return summary(np.array(ee_lid), np.array(angle), np.array(closed), lag, bool(info.get("is_success")))


def summary(ee_lid: np.ndarray, angle: np.ndarray, closed: np.ndarray, lag: list[float] | None, success: bool
            ) -> dict:
    """``ee_lid (S, 3)`` (m, lid frame), ``angle (S,)`` (degrees) and ``closed (S,)`` of one episode → its row."""
    row = {"success": success, "max_deg": round(float(angle.max()), 1), "end_deg": round(float(angle[-1]), 1)}
    row["fell_back"] = bool(angle.max() - angle[-1] >= FELL_BACK_DEG)
    if lag is None:
        return {**row, "close_lag_mm": None, "grasp_z_mm": None, "slip_mm": None}
    close = int(np.argmax(closed))
    held = min(close + 3, len(closed) - 1)
    end = max(held, int(np.argmax(angle)))
    reopened = np.flatnonzero(~closed[held:end + 1])
    if len(reopened):
        end = max(held, held + int(reopened[0]) - 1)
    rise = ee_lid[held:end + 1, 2] - ee_lid[held, 2]
    return {**row, "close_lag_mm": [round(value, 1) for value in lag],
            "grasp_z_mm": round(float(ee_lid[held, 2]) * 1e3, 1), "slip_mm": round(float(rise.max()) * 1e3, 1)}


def totals(rows: list[dict]) -> dict:
    """A runner's successes, medians and counts over its episode rows."""
    grasped = [row for row in rows if row["slip_mm"] is not None]
    return {
        "episodes": len(rows), "successes": sum(row["success"] for row in rows),
        "median_close_lag_mm": round(float(np.median([row["close_lag_mm"][1] for row in grasped])), 1),
        "median_grasp_z_mm": round(float(np.median([row["grasp_z_mm"] for row in grasped])), 1),
        "slipped": sum(row["slip_mm"] > SLIPPED_MM for row in grasped),
        "fell_back": sum(row["fell_back"] for row in rows),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--demo-seeds", type=seed_list, default=seed_list("0,100,200"),
                        help="each set's first demonstration seed (the dev split's sets)")
    parser.add_argument("--seeds", type=seed_list, default=seed_list("1000-1009"), help="episode seeds per set")
    parser.add_argument("--plan", choices=REPLAY_PLANS, default="consensus")
    parser.add_argument("--policy-path", help="an instant_policy pretrained_model directory, run from the same plan")
    parser.add_argument("--policy-field", action="append", default=[], metavar="NAME=VALUE",
                        help="a config field of the policy set for this run, VALUE read as JSON (n_action_steps=4)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    runners = {"replay": None}
    if args.policy_path:
        fields = {name: json.loads(value) for name, value in (field.split("=", 1) for field in args.policy_field)}
        runners["policy"] = replay_policy(args.policy_path, args.plan, **fields)
    env = BulletTabletopEnv(TASK, BulletTabletopConfig(render_size=(64, 64)))
    rows = {name: [] for name in runners}
    try:
        for demo_seed in args.demo_seeds:
            demonstrations = scripted_demonstrations(TASK, demo_seed, 2, "instant")
            for seed in args.seeds:
                episode = {name: run(env, demonstrations, args.plan, seed, runner) for name, runner in runners.items()}
                print(json.dumps({"demo_seed": demo_seed, "seed": seed, **episode}), flush=True)
                for name, row in episode.items():
                    rows[name].append(row)
    finally:
        env.close()
    print(json.dumps({name: totals(runner_rows) for name, runner_rows in rows.items()}))


if __name__ == "__main__":
    main()
