"""``lerobot-ip-dry-run``: run a policy open-loop on a recorded episode and draw its predicted EE trajectory over
the point cloud, so that frames, units and the gripper mapping can be checked before the arm moves.

    lerobot-ip-dry-run --demos demos/converted --repo-id local/converted --episode 1 --out dry_run.png
    lerobot-ip-dry-run ... --policy-path CKPT/pretrained_model       (an instant_policy checkpoint)

The policy sees the recorded frames of ``--episode`` one after the other (clouds, EE states, the task) and its
demonstrations are ``--num-demos`` other episodes of the same task in the same dataset. The PNG shows the first
frame's cloud from above and from the side, the recorded EE path, the predicted EE path (circles where the
predicted gripper is closed) and the EE frame at the first frame (x red, y green, z blue: z must point along the
approach, into the objects for a top-down grasp). The printed summary gives the distance between the predicted
and the recorded path; nothing is sent to a robot.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..contract import POINTCLOUD_KEY, STATE_KEY, poses_from_vectors


def predict_episode(policy, preprocessor, postprocessor, demo) -> np.ndarray:
    """Actions ``(F, 8)`` the policy gives on the recorded frames of ``demo`` (a ``Demonstration``), fed in order."""
    import torch

    policy.reset()
    actions = []
    for frame in range(demo.num_frames):
        batch = {
            POINTCLOUD_KEY: torch.from_numpy(demo.points_world[frame])[None],
            STATE_KEY: torch.from_numpy(demo.state[frame])[None],
            "task": [demo.task],
        }
        with torch.inference_mode():
            action = postprocessor(policy.select_action(preprocessor(batch)))
        actions.append(action[0].detach().cpu().numpy())
    return np.stack(actions)


def draw_dry_run(demo, predicted: np.ndarray, path: Path, title: str) -> None:
    """The PNG of the module docstring: ``demo`` (recorded episode), ``predicted (F, 8)`` actions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cloud, recorded = demo.points_world[0], demo.state[:, :3]
    start, _ = poses_from_vectors(demo.state[0])
    figure, axes = plt.subplots(1, 2, figsize=(11, 5))
    for axis, (i, j, names) in zip(axes, [(0, 1, "top view: x, y (m)"), (0, 2, "side view: x, z (m)")], strict=True):
        axis.scatter(cloud[:, i], cloud[:, j], s=1, c="0.6", label="cloud, first frame")
        axis.plot(recorded[:, i], recorded[:, j], "-", c="tab:blue", lw=2, label="recorded EE")
        axis.plot(predicted[:, i], predicted[:, j], "--", c="tab:orange", lw=2, label="predicted EE")
        closed = predicted[:, 7] < 0.5
        axis.scatter(predicted[closed, i], predicted[closed, j], s=18, facecolors="none", edgecolors="tab:orange",
                     label="predicted gripper closed")
        for column, colour in zip(range(3), ("r", "g", "b"), strict=True):
            tip = start[:3, 3] + 0.05 * start[:3, column]
            axis.plot([start[i, 3], tip[i]], [start[j, 3], tip[j]], c=colour, lw=2)
        axis.set_aspect("equal")
        axis.set_title(names)
    axes[0].legend(loc="best", fontsize=8)
    figure.suptitle(title)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def load_policy(policy_path: str | None, num_demos: int):
    """``(policy, preprocessor, postprocessor)``: the checkpoint at ``policy_path``, else ``demo_replay``."""
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    if policy_path:
        from lerobot.configs.policies import PreTrainedConfig

        config = PreTrainedConfig.from_pretrained(policy_path)
        config.device = "cpu"
        policy = get_policy_class(config.type).from_pretrained(policy_path, config=config)
        overrides = {"device_processor": {"device": "cpu"}}
        pre, post = make_pre_post_processors(config, pretrained_path=policy_path, preprocessor_overrides=overrides)
        return policy, pre, post
    from ..baselines.configuration_demo_replay import DemoReplayConfig

    config = DemoReplayConfig(num_demos=num_demos, device="cpu")
    policy = get_policy_class("demo_replay")(config)
    pre, post = make_pre_post_processors(config)
    return policy, pre, post


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="lerobot-ip-dry-run", description=__doc__.split("\n\n")[0])
    parser.add_argument("--demos", type=Path, required=True, help="a dataset in the data contract (converted)")
    parser.add_argument("--repo-id", required=True)
    parser.add_argument("--episode", type=int, default=0, help="the recorded episode to run on")
    parser.add_argument("--num-demos", type=int, default=1, help="other episodes of its task used as demonstrations")
    parser.add_argument("--policy-path", help="a pretrained_model directory (default: the demo_replay baseline)")
    parser.add_argument("--out", type=Path, default=Path("outputs/dry_run.png"))
    args = parser.parse_args(argv)
    from ..data.demonstrations import DemonstrationError, open_demo_dataset, read_demonstration

    try:
        dataset = open_demo_dataset(args.repo_id, args.demos)
        if not 0 <= args.episode < dataset.meta.total_episodes:
            raise DemonstrationError(f"--episode {args.episode}: the dataset has {dataset.meta.total_episodes} episodes")
        task = dataset.meta.episodes[args.episode]["tasks"][0]
        others = [int(e["episode_index"]) for e in dataset.meta.episodes
                  if task in list(e["tasks"]) and int(e["episode_index"]) != args.episode]
        if len(others) < args.num_demos:
            raise DemonstrationError(f"task {task!r} has {len(others)} other episodes, --num-demos {args.num_demos}")
        recorded = read_demonstration(dataset, args.episode, task)
        demos = [read_demonstration(dataset, index, task) for index in others[: args.num_demos]]
        policy, preprocessor, postprocessor = load_policy(args.policy_path, args.num_demos)
        policy.set_demonstrations(demos)
        predicted = predict_episode(policy, preprocessor, postprocessor, recorded)
    except (DemonstrationError, FileNotFoundError, ValueError) as error:
        print(f"lerobot-ip-dry-run: error: {error}", file=sys.stderr)
        return 2
    distance = np.linalg.norm(predicted[:, :3] - recorded.state[:, :3], axis=1)
    name = Path(args.policy_path).name if args.policy_path else "demo_replay"
    draw_dry_run(recorded, predicted, args.out, f"dry run of {name} on episode {args.episode} ({task})")
    print(
        f"{task}, episode {args.episode}, {recorded.num_frames} frames: predicted vs recorded EE position "
        f"{100 * distance.mean():.1f} cm mean, {100 * distance.max():.1f} cm max; gripper closes at predicted step "
        f"{int(np.argmax(predicted[:, 7] < 0.5)) if (predicted[:, 7] < 0.5).any() else 'never'}, recorded "
        f"{int(np.argmax(recorded.action[:, 7] < 0.5)) if (recorded.action[:, 7] < 0.5).any() else 'never'}; "
        f"wrote {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
