"""Recording scripted demonstrations of ``bullet_tabletop`` tasks as LeRobotDatasets (``lerobot-ip-record-demos``).

Recorded datasets follow docs/design.md §4 exactly (``observation.pointcloud``, ``observation.state`` = the state
before the action, ``action`` = the commanded EE target, ``task`` = the task name, 10 fps); ``with_images`` adds an
``observation.images.scene`` RGB render for viewing. Only successful demonstrations are written: a failed seed is
skipped and the next one tried (at most ``max_attempts`` seeds per episode).

``obs_type="rgbd"`` records what a robot with depth cameras records instead of the segmented cloud: one raw depth
image per camera (``observation.images.camera<i>_depth``, uint16 millimetres, a LeRobot depth feature whose ``info``
carries the camera's calibration), ``observation.joint_positions (9,)``, ``observation.state`` and ``action``;
``lerobot-ip-convert`` turns it into the data contract.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

IMAGE_KEY = "observation.images.scene"
JOINT_POSITIONS_KEY = "observation.joint_positions"


def depth_key(camera_index: int) -> str:
    return f"observation.images.camera{camera_index}_depth"


def rgbd_features(env) -> dict[str, dict]:
    """LeRobot features of an rgbd recording of ``env``: state, action, joint state, one depth image per camera
    (uint16 mm, flagged ``is_depth_map``, with its ``camera_calibration`` in ``info``)."""
    from ..contract import ACTION_KEY, STATE_KEY
    from ..data.lerobot_format import contract_features
    from ..perception.calibration import CALIBRATION_INFO_KEY, CameraCalibration
    from .robot import JOINT_NAMES

    contract = contract_features()
    features = {
        STATE_KEY: contract[STATE_KEY],
        ACTION_KEY: contract[ACTION_KEY],
        JOINT_POSITIONS_KEY: {"dtype": "float32", "shape": (len(JOINT_NAMES),), "names": list(JOINT_NAMES)},
    }
    width, height = env.config.depth_resolution
    for index, (intrinsics, pose) in enumerate(zip(env.camera_intrinsics(), env.camera_poses(), strict=True)):
        entry = {
            "name": f"camera{index}",
            "width": width,
            "height": height,
            "fx": float(intrinsics[0, 0]),
            "fy": float(intrinsics[1, 1]),
            "cx": float(intrinsics[0, 2]),
            "cy": float(intrinsics[1, 2]),
            "T_world_camera": pose.tolist(),
            "depth_unit": "mm",
        }
        CameraCalibration.from_dict(entry, where=f"{env.task} camera {index}")  # checked before recording
        features[depth_key(index)] = {
            "dtype": "image",
            "shape": (height, width, 1),
            "names": ["height", "width", "channels"],
            "info": {"is_depth_map": True, "depth_unit": "mm", CALIBRATION_INFO_KEY: entry},
        }
    return features


def _write_rgbd(dataset, episode, label: str) -> None:
    from ..contract import ACTION_KEY, STATE_KEY

    for index in range(episode.num_frames):
        frame = {
            STATE_KEY: np.ascontiguousarray(episode.state[index], dtype=np.float32),
            ACTION_KEY: np.ascontiguousarray(episode.action[index], dtype=np.float32),
            JOINT_POSITIONS_KEY: np.ascontiguousarray(episode.joint_positions[index], dtype=np.float32),
            "task": label,
        }
        for camera, depth in enumerate(episode.depth[index]):
            millimetres = np.round(depth * 1000.0).clip(0, np.iinfo(np.uint16).max).astype(np.uint16)
            frame[depth_key(camera)] = millimetres[:, :, None]
        dataset.add_frame(frame)
    dataset.save_episode()


def record(
    task: str,
    episodes: int,
    out: Path,
    repo_id: str,
    seed: int,
    with_images: bool = False,
    overwrite: bool = False,
    task_module: str | None = None,
    max_attempts: int = 5,
    obs_type: str = "pointcloud",
    label: str | None = None,
) -> dict:
    """Record ``episodes`` successful scripted demonstrations of ``task`` (seeds ``seed``, ``seed + 1``, …);
    ``obs_type="rgbd"`` records raw depth and joint states instead of segmented clouds (module docstring).
    ``label``: the ``task`` string the episodes are written under (default ``task``): another task's name records
    the context-swap control, this task's demonstrations handed to a policy as the other task's."""
    from ..data.lerobot_format import (
        DEFAULT_FPS,
        contract_features,
        create_dataset,
        write_episode,
    )
    from .env import BulletTabletopConfig, BulletTabletopEnv
    from .rollout import run_episode

    label = task if label is None else label
    if with_images and obs_type == "rgbd":
        raise ValueError("--with-images records segmented-cloud datasets only; rgbd recordings hold depth images")
    if out.exists():
        if not overwrite:
            raise FileExistsError(f"{out} already exists; pass --overwrite to replace it")
        shutil.rmtree(out)
    # a demonstration ends at its first step in the goal state, whatever criterion evaluations use: the same
    # demonstration sets serve the held and the instant success criteria
    env = BulletTabletopEnv(task, BulletTabletopConfig(obs_type=obs_type, success="instant"), task_module=task_module)
    try:
        if obs_type == "rgbd":
            from lerobot.datasets import LeRobotDataset

            dataset = LeRobotDataset.create(repo_id, fps=DEFAULT_FPS, features=rgbd_features(env), root=out, use_videos=False)
        elif with_images:
            from lerobot.datasets import LeRobotDataset

            height, width = env.config.render_size[1], env.config.render_size[0]
            features = contract_features(env.config.num_points)
            features[IMAGE_KEY] = {
                "dtype": "image",
                "shape": (height, width, 3),
                "names": ["height", "width", "channels"],
            }
            dataset = LeRobotDataset.create(repo_id, fps=DEFAULT_FPS, features=features, root=out, use_videos=False)
        else:
            dataset = create_dataset(repo_id, out, fps=DEFAULT_FPS, num_points=env.config.num_points)
        recorded, failed, next_seed = [], [], seed
        while len(recorded) < episodes:
            if len(failed) >= max_attempts * episodes:
                raise RuntimeError(f"the scripted demonstrator of {task!r} failed on seeds {failed}")
            episode = run_episode(env, next_seed, "scripted", with_images=with_images)
            if not episode.success:
                failed.append(next_seed)
            elif obs_type == "rgbd":
                _write_rgbd(dataset, episode, label)
                recorded.append(next_seed)
            elif with_images:
                _write_with_images(dataset, episode, label)
                recorded.append(next_seed)
            else:
                write_episode(dataset, episode.points, episode.state, episode.action, label)
                recorded.append(next_seed)
            next_seed += 1
        dataset.finalize()
    finally:
        env.close()
    return {
        "task": task,
        "label": label,
        "repo_id": repo_id,
        "root": str(out),
        "episodes": len(recorded),
        "seeds": recorded,
        "failed_seeds": failed,
    }


def _write_with_images(dataset, episode, label: str) -> None:
    from ..contract import ACTION_KEY, POINTCLOUD_KEY, STATE_KEY

    for index in range(episode.num_frames):
        dataset.add_frame(
            {
                POINTCLOUD_KEY: np.ascontiguousarray(episode.points[index], dtype=np.float32),
                STATE_KEY: np.ascontiguousarray(episode.state[index], dtype=np.float32),
                ACTION_KEY: np.ascontiguousarray(episode.action[index], dtype=np.float32),
                IMAGE_KEY: episode.images[index],
                "task": label,
            }
        )
    dataset.save_episode()


def check(tasks: list[str], episodes: int, seed: int, task_module: str | None = None) -> list[dict]:
    """Success rate of the scripted demonstrator and of a do-nothing policy over ``episodes`` seeds per task.

    Runs without camera rendering (success depends on physics only), so a full table takes minutes.
    """
    from .env import BulletTabletopEnv
    from .rollout import run_episode

    rows = []
    for task in tasks:
        env = BulletTabletopEnv(task, observe_pointcloud=False, task_module=task_module)
        try:
            seeds = range(seed, seed + episodes)
            scripted = [run_episode(env, s, "scripted") for s in seeds]
            idle = [run_episode(env, s, "idle").success for s in seeds]
        finally:
            env.close()
        rows.append(
            {
                "task": task,
                "episodes": episodes,
                "scripted_success": sum(e.success for e in scripted) / episodes,
                "idle_success": sum(idle) / episodes,
                "scripted_failed_seeds": [e.seed for e in scripted if not e.success],
                "mean_demo_frames": round(float(np.mean([e.num_frames for e in scripted])), 1),
            }
        )
    return rows


def check_table(rows: list[dict]) -> str:
    """``check``'s rows as text: task, scripted and do-nothing success, the scripted demonstrator's failed seeds."""
    lines = [f"{'task':<16} {'scripted':>9} {'do-nothing':>11}  failed seeds"]
    lines += [f"{row['task']:<16} {row['scripted_success']:>9.0%} {row['idle_success']:>11.0%}  "
              f"{row['scripted_failed_seeds']}" for row in rows]
    return "\n".join(lines)
