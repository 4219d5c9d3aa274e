"""A policy run open-loop on a recorded episode, its predicted EE trajectory drawn over the point cloud, so that
frames, units and the gripper mapping can be checked before the arm moves.

The policy sees the recorded frames of one episode one after the other (clouds, EE states, the task) and its
demonstrations are other episodes of the same task in the same dataset. The PNG shows the first frame's cloud from
above and from the side, the recorded EE path, the predicted EE path (circles where the predicted gripper is closed)
and the EE frame at the first frame (x red, y green, z blue: z must point along the approach, into the objects for a
top-down grasp). Nothing is sent to a robot. ``lerobot-ip-dry-run`` is the command line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..contract import POINTCLOUD_KEY, STATE_KEY, poses_from_vectors
from ..data.demonstrations import Demonstration, DemonstrationError, open_demo_dataset, read_demonstration


@dataclass
class DryRun:
    """The actions ``predicted (F, 8)`` (EE xyz, quaternion xyzw, gripper; world frame) that the policy ``policy_name``
    gave on the ``F`` frames of the ``recorded`` episode ``episode`` of ``task``."""

    task: str
    episode: int
    policy_name: str
    recorded: Demonstration
    predicted: np.ndarray

    def position_error(self) -> np.ndarray:
        """``(F,)`` metres between the predicted and the recorded EE position of every frame."""
        return np.linalg.norm(self.predicted[:, :3] - self.recorded.state[:, :3], axis=1)

    def title(self) -> str:
        """The picture's title: the policy, the episode and its task."""
        return f"dry run of {self.policy_name} on episode {self.episode} ({self.task})"


def first_closed_step(actions: np.ndarray) -> int | None:
    """The first step of ``actions (F, 8)`` whose gripper is closed (below 0.5), or None if it never closes."""
    closed = actions[:, 7] < 0.5
    return int(np.argmax(closed)) if closed.any() else None


def load_policy_or_demo_replay(policy_path: str | None, num_demos: int):
    """``(policy, preprocessor, postprocessor)`` on the CPU: the checkpoint at ``policy_path`` (a
    ``pretrained_model`` directory of any registered policy type), else the ``demo_replay`` baseline."""
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


def predict_episode(policy, preprocessor, postprocessor, demo: Demonstration) -> np.ndarray:
    """Actions ``(F, 8)`` the policy gives on the recorded frames of ``demo``, fed in order."""
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


def draw_dry_run(run: DryRun, path: Path) -> None:
    """The PNG of the module docstring at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    demo, predicted = run.recorded, run.predicted
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
    figure.suptitle(run.title())
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def dry_run(demos: Path, repo_id: str, episode: int, num_demos: int, policy_path: str | None) -> DryRun:
    """Run the checkpoint at ``policy_path`` (else ``demo_replay``) on episode ``episode`` of the dataset at
    ``demos``, with the first ``num_demos`` other episodes of its task as demonstrations; ``DemonstrationError`` when
    the episode or enough other episodes are missing."""
    dataset = open_demo_dataset(repo_id, demos)
    if not 0 <= episode < dataset.meta.total_episodes:
        raise DemonstrationError(f"--episode {episode}: the dataset has {dataset.meta.total_episodes} episodes")
    task = dataset.meta.episodes[episode]["tasks"][0]
    others = [int(e["episode_index"]) for e in dataset.meta.episodes
              if task in list(e["tasks"]) and int(e["episode_index"]) != episode]
    if len(others) < num_demos:
        raise DemonstrationError(f"task {task!r} has {len(others)} other episodes, --num-demos {num_demos}")
    recorded = read_demonstration(dataset, episode, task)
    context = [read_demonstration(dataset, index, task) for index in others[:num_demos]]
    policy, preprocessor, postprocessor = load_policy_or_demo_replay(policy_path, num_demos)
    policy.set_demonstrations(context)
    predicted = predict_episode(policy, preprocessor, postprocessor, recorded)
    name = Path(policy_path).name if policy_path else "demo_replay"
    return DryRun(task, episode, name, recorded, predicted)
