"""How much a replay loses because the suite's demonstrations stop at their first step in the goal state.

``lerobot-ip-record-demos`` and the evaluations end a scripted demonstration at its first step in the goal state
(``sim.recording``: the same sets serve the held and the instant criterion). A task whose goal is a threshold crossed
mid-motion (``open_box``: the lid beyond 0.9 rad, which the scripted arc passes on its way to 1.1 rad) is then shown
stopping just past it, and its replay in another scene ends on either side. For each demonstration seed set, two
demonstrations are recorded in memory as the recording does (the scripted demonstrator, failed seeds skipped) and
again run on to the end of the scripted actions (ended by the held criterion instead); each variant is replayed onto
the same episode seeds (``replay.priors.plan_onto_live``, the plan executed by control step as ``demo_replay`` does),
and with ``--policy-path`` an ``instant_policy`` checkpoint is run on them too, handed each variant's demonstrations
(``set_demonstrations``) and denoising from the same plan. Prints one JSON line per episode (success of each variant;
for the box tasks the lid's final angle, degrees), then the successes and the episodes only one variant succeeds in.

    python -m workbench.scripts.demo_end_margin open_box --demo-seeds 0,100,200 --seeds 1000-1009 --plan consensus \
        [--policy-path lerobot_instant_policy/assets/checkpoints/instant_policy_replay_prior]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from lerobot_instant_policy.data.demonstrations import Demonstration
from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy
from lerobot_instant_policy.replay.plan import REPLAY_PLANS
from lerobot_instant_policy.sim.env import BulletTabletopConfig, BulletTabletopEnv
from lerobot_instant_policy.sim.rollout import run_episode
from workbench.replay_episodes import episode_action, replay_policy, seed_list, start_episode

VARIANTS = {"first_goal": "instant", "run_on": "held"}  # how a demonstration ends → the success criterion ending it


def scripted_demonstrations(task: str, first_seed: int, count: int, success: str, max_attempts: int = 5
                            ) -> list[Demonstration]:
    """``count`` successful scripted demonstrations from ``first_seed`` on, each ended by the ``success`` criterion
    (``instant``: its first step in the goal state, as ``sim.recording`` records)."""
    env = BulletTabletopEnv(task, BulletTabletopConfig(success=success))
    try:
        sources, seed = [], first_seed
        while len(sources) < count and seed < first_seed + max_attempts * count:
            episode = run_episode(env, seed, "scripted")
            if episode.success:
                sources.append(Demonstration(episode.points, episode.state, episode.action, task))
            seed += 1
    finally:
        env.close()
    if len(sources) < count:
        raise RuntimeError(f"the scripted demonstrator of {task!r} failed from seed {first_seed} on")
    return sources


def run(env: BulletTabletopEnv, task: str, demonstrations: list[Demonstration], plan_name: str, seed: int,
        policy: InstantPolicyPolicy | None = None) -> dict:
    """One episode of ``seed``: the ``plan_name`` plan of ``demonstrations`` executed by control step, or
    ``policy`` handed them."""
    observation, plan = start_episode(env, task, demonstrations, plan_name, seed, policy)
    info = {}
    for step in range(env._max_episode_steps):
        action = episode_action(policy, plan, step, observation, task)
        observation, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    row = {"success": bool(info.get("is_success")), "plan_steps": len(plan)}
    if hasattr(env.task_impl, "angle"):
        row["end_deg"] = round(float(np.degrees(env.task_impl.angle(env.scene))), 1)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task", help="a bullet_tabletop task")
    parser.add_argument("--demo-seeds", type=seed_list, default=seed_list("0,100,200"),
                        help="each set's first demonstration seed (the dev split's sets)")
    parser.add_argument("--num-demos", type=int, default=2)
    parser.add_argument("--seeds", type=seed_list, default=seed_list("1000-1009"), help="episode seeds per set")
    parser.add_argument("--plan", choices=REPLAY_PLANS, default="consensus")
    parser.add_argument("--policy-path", help="an instant_policy pretrained_model directory, run beside the replay "
                                              "from the same plan (its own strength and K)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    policy = replay_policy(args.policy_path, args.plan) if args.policy_path else None
    runners = {"replay": None, **({"policy": policy} if policy is not None else {})}
    columns = [f"{runner}/{variant}" for runner in runners for variant in VARIANTS]
    env = BulletTabletopEnv(args.task, BulletTabletopConfig(render_size=(64, 64)))
    totals = {column: 0 for column in columns}
    only = {column: 0 for column in columns}
    try:
        for demo_seed in args.demo_seeds:
            demonstrations = {variant: scripted_demonstrations(args.task, demo_seed, args.num_demos, success)
                              for variant, success in VARIANTS.items()}
            for seed in args.seeds:
                rows = {f"{name}/{variant}": run(env, args.task, demonstrations[variant], args.plan, seed, runner)
                        for name, runner in runners.items() for variant in VARIANTS}
                print(json.dumps({"demo_seed": demo_seed, "seed": seed, **rows}), flush=True)
                for column, row in rows.items():  # "only": against the other variant of the same runner
                    runner = column.split("/")[0]
                    others = [other for name, other in rows.items() if name != column and name.startswith(runner)]
                    totals[column] += row["success"]
                    only[column] += row["success"] and not any(other["success"] for other in others)
    finally:
        env.close()
    print(json.dumps({"episodes": len(args.demo_seeds) * len(args.seeds), "successes": totals,
                      "only_this_variant_succeeds": only}))


if __name__ == "__main__":
    main()
