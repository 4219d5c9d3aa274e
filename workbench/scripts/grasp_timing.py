"""When a MetaWorld grasp closes the fingers, against when the EE gets down to the object: the replay and a policy
run from the replay prior, episode by episode on the same seeds.

MetaWorld's fingers take several control steps to close, so its scripted experts command the close while the hand
is still descending, timed to their own speed; a replay executes the same commands at the same pace. For each
episode seed, the replay plan is made at the first observation as the policy makes it
(``replay.priors.plan_onto_live``) and executed by control step (``demo_replay``'s reading), then the policy runs
on the same seed. Per episode: success, the first step that commands a close, the first step at which the EE
(MetaWorld's ``tcp_center``) is within 15 mm of the object's height (the object: the first position in MetaWorld's
state vector, ``environment_state[4:7]``, the task's object or its grasp site: peg-insert-side's ``pegGrasp``), the
steps between them, the EE's horizontal offset from the object
there, and whether the object ever rose 2 cm above where it started. Prints one JSON line per episode and mode,
then each mode's medians.

    MUJOCO_GL=osmesa python -m workbench.scripts.grasp_timing peg-insert-side-v3 \
        outputs/results/mt10_fixed_dev/demos/peg-insert-side-v3-n2-s0 \
        --policy-path lerobot_instant_policy/assets/checkpoints/instant_policy_replay_prior \
        --plan consensus --seeds 1000-1009
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from lerobot_instant_policy.data.demonstrations import load_demonstrations
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.replay.plan import REPLAY_PLANS
from lerobot_instant_policy.replay.priors import plan_onto_live
from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv
from workbench.replay_episodes import episode_action, replay_policy, seed_list

LIFTED_M = 0.02  # the object counts as lifted once it rises this far above its first height


def run_episode(env: MetaworldPointCloudEnv, seed: int, task: str, demonstrations, plan_name: str,
                policy: InstantPolicyPolicy | None) -> dict:
    """One episode from ``seed``: the replay (``policy`` None) or ``policy``; the per-step record's summary."""
    observation, _ = env.reset(seed=seed)
    plan = plan_onto_live(task, demonstrations, observation["pointcloud"], plan_name).actions
    if policy is not None:
        policy.reset()
        torch.manual_seed(seed)
    ee, obj, close, info = [], [], [], {}
    for step in range(env._max_episode_steps):
        action = episode_action(policy, plan, step, observation, task)
        ee.append(observation["agent_pos"][:3].copy())
        obj.append(observation["environment_state"][4:7].copy())
        close.append(bool(action[7] < 0.5))
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated or info.get("success"):
            break
    return summary(np.array(ee), np.array(obj), np.array(close), bool(info.get("success")))


def summary(ee: np.ndarray, obj: np.ndarray, close: np.ndarray, success: bool, arrive_m: float = 0.015) -> dict:
    """``ee (S, 3)``, ``obj (S, 3)`` (world frame, m) and ``close (S,)`` (the step's command closes) → the episode's
    grasp figures (module docstring)."""
    close_step = int(np.argmax(close)) if close.any() else None
    down = np.flatnonzero(ee[:, 2] < obj[:, 2] + arrive_m)
    arrive_step = int(down[0]) if len(down) else None
    offset_mm = None if arrive_step is None else round(1000 * float(np.linalg.norm(ee[arrive_step, :2]
                                                                                   - obj[arrive_step, :2])), 1)
    return {"success": success, "steps": len(ee), "close_step": close_step, "arrive_step": arrive_step,
            "arrive_after_close": None if close_step is None or arrive_step is None else arrive_step - close_step,
            "offset_mm": offset_mm, "lifted": bool((obj[:, 2] > obj[0, 2] + LIFTED_M).any())}


def medians(rows: list[dict]) -> dict:
    def median(key):
        values = [row[key] for row in rows if row[key] is not None]
        return float(np.median(values)) if values else None
    return {"episodes": len(rows), "successes": sum(row["success"] for row in rows),
            "lifted": sum(row["lifted"] for row in rows), "arrive_after_close_median": median("arrive_after_close"),
            "offset_mm_median": median("offset_mm")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task", help="a MetaWorld v3 task")
    parser.add_argument("demos", help="the demonstration dataset's root (repo id local/<task>)")
    parser.add_argument("--policy-path", help="an instant_policy pretrained_model directory (none: the replay only)")
    parser.add_argument("--plan", choices=REPLAY_PLANS, default="consensus")
    parser.add_argument("--seeds", type=seed_list, default=seed_list("1000-1009"))
    parser.add_argument("--num-demos", type=int, default=2)
    parser.add_argument("--pointcloud-every", type=int, default=8, help="as the evaluations run MetaWorld")
    args = parser.parse_args()
    torch.set_num_threads(1)

    demonstrations = load_demonstrations(f"local/{args.task}", args.demos, args.task, args.num_demos)
    policy = None
    if args.policy_path:
        policy = replay_policy(args.policy_path, args.plan, demo_repo_id=f"local/{args.task}", demo_root=args.demos,
                               num_demos=args.num_demos)
    env = MetaworldPointCloudEnv(args.task, pointcloud_every=args.pointcloud_every, render_size=64)
    modes = {"replay": None, **({"policy": policy} if policy is not None else {})}
    rows = {mode: [] for mode in modes}
    for seed in args.seeds:
        for mode, runner in modes.items():
            row = {"mode": mode, "seed": seed, **run_episode(env, seed, args.task, demonstrations, args.plan, runner)}
            rows[mode].append(row)
            print(json.dumps(row), flush=True)
    env.close()
    print(json.dumps({mode: medians(mode_rows) for mode, mode_rows in rows.items()}))


if __name__ == "__main__":
    main()
