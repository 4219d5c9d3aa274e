"""Where the goal gets lost: linear probes of the motion target on σ's and φ's output at the current gripper nodes.

On a reach pseudo-task (rung 1) the motion to predict is fixed by the goal: the live episode's final EE position
expressed in the current EE frame, ``goal_ee (3,)``, and, over the action horizon, the position of the last action of
the chunk, ``chunk_ee (3,)``. The scene alone cannot tell either (the anchor object and the pose on it are drawn per
task); the demonstrations can. For a checkpoint this script extracts, at every sampled frame of each task's live (last)
episode,

- ``sigma``: σ's output at the current gripper nodes ``(G·H,)``, which sees the live scene but no demonstration;
- ``phi``: φ's output at the same nodes with the task's first two demonstrations (L = 10 waypoints), the only way
  from the demonstrations to the actions;
- ``phi_swap``: φ's output with the next task's demonstrations relabelled as this task's (the context swap of
  ``lerobot-ip-action-error``),
- ``sigma_demo_end``: ``sigma`` beside σ's output at the demonstrations' last waypoints (mean over the two), the
  raw material φ has to compare: what a linear read-out of both together can tell, without φ,

fits a ridge regression from each feature set to each target on the frames of the *training* tasks, and reports on the
*held-out* tasks (new tasks on new objects) the error of its prediction relative to holding still (predicting 0):

    probe error / hold = mean ‖ŷ − y‖ / mean ‖y‖

``phi`` well below ``sigma`` held out means φ's output carries goal information that carries over to new tasks, and
what fails to use it is ψ and the diffusion head. ``phi`` close to ``sigma`` means φ itself does not extract it in
a form that generalises. ``phi_swap`` read with the ``phi`` probe shows how much of that depends on the right
demonstrations. The ridge strength is picked by 5-fold cross-validation over training tasks (folds never split a
task). Two more figures: the cross-validated error over training tasks (new tasks, but of the training objects),
and a probe fitted on every other frame of the training tasks and tested on the remaining frames of the *same*
tasks, which shows what the features hold about tasks the network has seen (what it may have memorised). With
``--mlp`` a 2-layer MLP probe is fitted too (the goal is a composition of two poses, which a linear read-out
cannot form), stopped early on a fifth of the training tasks.

    python workbench/scripts/goal_probe.py CHECKPOINT_DIR TRAIN_ROOT HELD_OUT_ROOT [--train-tasks 120] [--frames 15] [--mlp]
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
import torch

from lerobot_instant_policy.contract import poses_from_vectors_torch
from lerobot_instant_policy.data.demonstrations import open_demo_dataset, read_demonstration
from lerobot_instant_policy.evaluation.checkpoints import load_policy
from lerobot_instant_policy.geometry.rigid_torch import invert_rigid, transform_points

RIDGE_STRENGTHS = (1e-1, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5)


def read_tasks(root: str, count: int) -> list[tuple[str, list]]:
    """The first ``count`` tasks of the dataset at ``root`` (by first episode), each with its episodes in order."""
    dataset = open_demo_dataset(f"local/{root.rstrip('/').split('/')[-1]}", root)
    by_task: dict[str, list[int]] = {}
    for episode in dataset.meta.episodes:
        by_task.setdefault(str(episode["tasks"][0]), []).append(int(episode["episode_index"]))
    chosen = sorted(by_task.items(), key=lambda item: min(item[1]))[:count]
    # first two demonstrations and the live (last) episode: all the probe reads
    return [(task, [read_demonstration(dataset, e, task) for e in (*sorted(eps)[:2], sorted(eps)[-1])])
            for task, eps in chosen]


@torch.inference_mode()
def task_features(policy, task: str, demos: list, live, frames: np.ndarray, swap_demos: list) -> dict[str, np.ndarray]:
    """Features ``(F, G·H)`` and targets ``(F, 3)`` at ``frames`` of ``live``."""
    network = policy.network
    state = torch.from_numpy(live.state[frames])
    T_world_ee, gripper_open = poses_from_vectors_torch(state)
    gripper = (gripper_open > 0.5).to(state.dtype)
    positions, scene_features = network.encode_observation(torch.from_numpy(live.points_world[frames]), T_world_ee)
    out = {"sigma": network._observation_gripper_features(positions, scene_features, gripper, leading=(len(frames),))}
    for key, context_demos in (("phi", demos), ("phi_swap", swap_demos)):
        policy.set_demonstrations([dataclasses.replace(d, task=task) for d in context_demos], num_waypoints=10)
        task_context = policy.task_context(task)
        waypoints = task_context.waypoint_features
        context = network.encode_context(
            task_context.demos.expand(len(frames)), torch.from_numpy(live.points_world[frames]), T_world_ee, gripper,
            scene_geometry=(positions, scene_features),
            demo_waypoint_features=waypoints.expand(len(frames), *waypoints.shape[1:]),
        )
        out[key] = context.current_gripper_features
        if key == "phi":  # σ at the demonstrations' last waypoints (mean over demos), beside σ at the current frame
            last = waypoints[:, :, -1].mean(1).expand(len(frames), -1, -1)
            out["sigma_demo_end"] = torch.cat([out["sigma"], last], dim=-1)
    out = {key: value.flatten(1).float().numpy() for key, value in out.items()}
    T_ee_world = invert_rigid(T_world_ee)
    horizon = policy.config.horizon
    chunk_end = np.minimum(frames + horizon - 1, len(live.action) - 1)
    goal_world = torch.from_numpy(np.repeat(live.state[-1:, :3], len(frames), axis=0))
    chunk_world = torch.from_numpy(live.action[chunk_end, :3])
    out["goal_ee"] = transform_points(T_ee_world, goal_world[:, None])[:, 0].numpy()
    out["chunk_ee"] = transform_points(T_ee_world, chunk_world[:, None])[:, 0].numpy()
    return out


def collect(policy, tasks: list[tuple[str, list]], frames_per_task: int) -> dict[str, np.ndarray]:
    """Stacked features and targets of every task, with ``task_index (F,)``."""
    rows: dict[str, list[np.ndarray]] = {}
    for index, (task, (first, second, live)) in enumerate(tasks):
        swap = tasks[(index + 1) % len(tasks)][1][:2]
        frames = np.unique(np.linspace(0, live.num_frames - 1, frames_per_task).round().astype(int))
        for key, value in task_features(policy, task, [first, second], live, frames, swap).items():
            rows.setdefault(key, []).append(value)
        rows.setdefault("task_index", []).append(np.full(len(frames), index))
        rows.setdefault("frame_rank", []).append(np.arange(len(frames)))
    return {key: np.concatenate(value) for key, value in rows.items()}


def fit_ridge(x: np.ndarray, y: np.ndarray, strength: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ridge on standardised ``x``: ``(mean, scale, weights, bias)``."""
    mean, scale = x.mean(0), x.std(0) + 1e-6
    z = (x - mean) / scale
    weights = np.linalg.solve(z.T @ z + strength * np.eye(z.shape[1]), z.T @ (y - y.mean(0)))
    return mean, scale, weights, y.mean(0)


def predict(model, x: np.ndarray) -> np.ndarray:
    mean, scale, weights, bias = model
    return (x - mean) / scale @ weights + bias


def relative_error(predicted: np.ndarray, target: np.ndarray) -> float:
    return float(np.linalg.norm(predicted - target, axis=1).mean() / np.linalg.norm(target, axis=1).mean())


def task_folds(task_index: np.ndarray, folds: int = 5) -> list[np.ndarray]:
    return [np.isin(task_index, np.unique(task_index)[k::folds]) for k in range(folds)]


def cross_validated(x: np.ndarray, y: np.ndarray, task_index: np.ndarray) -> tuple[float, float]:
    """The best ridge strength by 5-fold CV over tasks, and its CV error / hold."""
    scores = {}
    for strength in RIDGE_STRENGTHS:
        predicted = np.empty_like(y)
        for test in task_folds(task_index):
            predicted[test] = predict(fit_ridge(x[~test], y[~test], strength), x[test])
        scores[strength] = relative_error(predicted, y)
    best = min(scores, key=scores.get)
    return best, scores[best]


def mlp_probe(x: np.ndarray, y: np.ndarray, task_index: np.ndarray, x_test: np.ndarray, epochs: int = 400) -> np.ndarray:
    """A 2-layer GELU MLP (256 wide) from standardised ``x`` to ``y``, AdamW full-batch, stopped at the epoch with the
    lowest error on a fifth of the training tasks held back; its predictions on ``x_test``."""
    generator = torch.Generator().manual_seed(0)
    mean, scale = x.mean(0), x.std(0) + 1e-6
    inputs = torch.from_numpy((x - mean) / scale).float()
    test_inputs = torch.from_numpy((x_test - mean) / scale).float()
    targets = torch.from_numpy(y).float()
    back = torch.from_numpy(task_folds(task_index)[0])
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], 256), torch.nn.GELU(), torch.nn.Linear(256, 256),
                              torch.nn.GELU(), torch.nn.Linear(256, y.shape[1]))
    optimizer = torch.optim.AdamW(net.parameters(), lr=1e-3, weight_decay=1e-2)
    best, best_state = float("inf"), None
    for _ in range(epochs):
        keep = torch.randperm(len(inputs), generator=generator)
        keep = keep[~back[keep]]
        for rows in keep.split(256):
            loss = (net(inputs[rows]) - targets[rows]).norm(dim=1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
        with torch.no_grad():
            error = (net(inputs[back]) - targets[back]).norm(dim=1).mean().item()
        if error < best:
            best, best_state = error, {k: v.clone() for k, v in net.state_dict().items()}
    net.load_state_dict(best_state)
    with torch.no_grad():
        return net(test_inputs).double().numpy()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint")
    parser.add_argument("train_root")
    parser.add_argument("held_out_root")
    parser.add_argument("--train-tasks", type=int, default=120)
    parser.add_argument("--held-out-tasks", type=int, default=24)
    parser.add_argument("--frames", type=int, default=15, help="frames per live episode, evenly spaced")
    parser.add_argument("--mlp", action="store_true", help="also a 2-layer MLP probe of each feature set")
    args = parser.parse_args()
    torch.manual_seed(0)
    policy = load_policy(args.checkpoint)
    train = collect(policy, read_tasks(args.train_root, args.train_tasks), args.frames)
    held = collect(policy, read_tasks(args.held_out_root, args.held_out_tasks), args.frames)
    result = {"checkpoint": args.checkpoint, "train_frames": len(train["sigma"]), "held_out_frames": len(held["sigma"])}
    for target in ("goal_ee", "chunk_ee"):
        for key in ("sigma", "sigma_demo_end", "phi"):
            strength, train_cv = cross_validated(train[key], train[target], train["task_index"])
            model = fit_ridge(train[key], train[target], strength)
            odd = train["frame_rank"] % 2 == 1  # seen tasks: fitted on every other frame, tested on the rest
            seen = fit_ridge(train[key][~odd], train[target][~odd], strength)
            figures = {"ridge": strength, "training_tasks_cv": round(train_cv, 3),
                       "training_tasks_other_frames": round(relative_error(predict(seen, train[key][odd]),
                                                                           train[target][odd]), 3),
                       "held_out": round(relative_error(predict(model, held[key]), held[target]), 3)}
            if args.mlp:
                figures["mlp_held_out"] = round(relative_error(
                    mlp_probe(train[key], train[target], train["task_index"], held[key]), held[target]), 3)
            if key == "phi":
                figures["held_out_swap"] = round(relative_error(predict(model, held["phi_swap"]), held[target]), 3)
            result[f"{target}/{key}"] = figures
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
