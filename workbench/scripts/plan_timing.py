"""How far a policy run from the replay prior falls behind or runs ahead of the plan it reads by control step.

For one ``bullet_tabletop`` task, demonstration set and episode seed: the replay plan is made at the first observation
as the policy makes it (``replay.priors.plan_onto_live`` of the demonstrations onto the first cloud); at control step
``k`` the plan hands the network its actions from ``k`` on. The EE's **lag** at step ``k`` is ``k − j``, with ``j`` the
plan step among ``k − window … k + window`` whose reached pose is nearest the EE (the pose the plan's action ``j − 1``
commands, step 0 the episode's start: ``lerobot_instant_policy.replay.timing``'s model; > 0: behind the plan). Prints
JSON: success, steps, and the lag's median, 90th percentile of its size and extremes, then every ``--every``-th step.

    python workbench/scripts/plan_timing.py stack_blocks CHECKPOINT outputs/results/suite_dev/demos/stack_blocks-n2-s0 \
        --seed 1000 --strength 0.25 --plan anchored
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from lerobot_instant_policy.data.demonstrations import load_demonstrations
from lerobot_instant_policy.replay.plan import REPLAY_PLANS
from lerobot_instant_policy.replay.priors import plan_onto_live
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from workbench.replay_episodes import episode_action, replay_policy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task")
    parser.add_argument("checkpoint", help="an instant_policy pretrained_model directory")
    parser.add_argument("demos", help="the demonstration dataset's root (repo id local/<task>)")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--num-demos", type=int, default=2)
    parser.add_argument("--window", type=int, default=30)
    parser.add_argument("--every", type=int, default=5)
    parser.add_argument("--strength", type=float, default=0.25, help="replay_init_strength")
    parser.add_argument("--plan", choices=REPLAY_PLANS, default="anchored")
    parser.add_argument("--inference-steps", type=int, help="K (default: the checkpoint's)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    fields = {"inference_steps": args.inference_steps} if args.inference_steps else {}
    policy = replay_policy(args.checkpoint, args.plan, demo_repo_id=f"local/{args.task}", demo_root=args.demos,
                           num_demos=args.num_demos, replay_init_strength=args.strength, **fields)
    policy.reset()
    demonstrations = load_demonstrations(f"local/{args.task}", args.demos, args.task, args.num_demos)
    env = BulletTabletopEnv(args.task, BulletTabletopConfig(render_size=(64, 64)))
    observation, _ = env.reset(seed=args.seed)
    plan = plan_onto_live(args.task, demonstrations, observation["pointcloud"], args.plan).actions
    reached = np.concatenate([observation["agent_pos"][None, :3], plan[:-1, :3]])  # (G, 3): the pose at each step
    rows, info = [], {}
    for step in range(env._max_episode_steps):
        action = episode_action(policy, plan, step, observation, args.task)
        last = len(plan) - 1  # past the plan's end its last action holds
        window = np.arange(min(max(step - args.window, 0), last), min(step + args.window, last) + 1)
        distances = np.linalg.norm(reached[window] - observation["agent_pos"][:3], axis=1)
        nearest = int(window[np.argmin(distances)])
        rows.append({"step": step, "lag": step - nearest, "off_path_mm": round(1000 * float(distances.min()), 1),
                     "gripper": float(action[7])})
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    lags = np.array([row["lag"] for row in rows])
    print(json.dumps({"task": args.task, "seed": args.seed, "success": bool(info.get("is_success")),
                      "steps": len(rows), "plan_steps": len(plan), "lag_median": float(np.median(lags)),
                      "abs_lag_p90": float(np.percentile(np.abs(lags), 90)), "lag_min": int(lags.min()),
                      "lag_max": int(lags.max())}))
    for row in rows[::args.every]:
        print(json.dumps(row))


if __name__ == "__main__":
    main()
