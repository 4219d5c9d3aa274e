"""The data contract (:mod:`..contract`) as LeRobot dataset features, and writing demonstrations into a dataset."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from ..contract import (
    ACTION_KEY,
    NUM_POINTS,
    POINTCLOUD_KEY,
    POINTCLOUD_NAMES,
    POSE_GRIPPER_NAMES,
    POSE_GRIPPER_SHAPE,
    STATE_KEY,
)

DEFAULT_FPS = 10


def contract_features(num_points: int = NUM_POINTS) -> dict[str, dict]:
    """LeRobot ``features`` for the point cloud, the EE state and the EE action (world frame, metres)."""
    pose = {"dtype": "float32", "shape": POSE_GRIPPER_SHAPE, "names": list(POSE_GRIPPER_NAMES)}
    return {
        POINTCLOUD_KEY: {"dtype": "float32", "shape": (num_points, 3), "names": list(POINTCLOUD_NAMES)},
        STATE_KEY: dict(pose),
        ACTION_KEY: dict(pose),
    }


def create_dataset(repo_id: str, root: Path, fps: int = DEFAULT_FPS, num_points: int = NUM_POINTS):
    """A new, empty LeRobotDataset at ``root`` (which must not exist) with the contract's features."""
    from lerobot.datasets import LeRobotDataset

    return LeRobotDataset.create(
        repo_id, fps=fps, features=contract_features(num_points), root=root, use_videos=False
    )


def write_episode(dataset, points: np.ndarray, state: np.ndarray, action: np.ndarray, task: str) -> None:
    """Append one episode: ``points (F, P, 3)``, ``state (F, 8)``, ``action (F, 8)`` (float32), ``task`` string."""
    frames = len(state)
    if points.shape[0] != frames or action.shape[0] != frames:
        raise ValueError(f"episode arrays disagree on length: {points.shape}, {state.shape}, {action.shape}")
    for index in range(frames):
        dataset.add_frame(
            {
                POINTCLOUD_KEY: np.ascontiguousarray(points[index], dtype=np.float32),
                STATE_KEY: np.ascontiguousarray(state[index], dtype=np.float32),
                ACTION_KEY: np.ascontiguousarray(action[index], dtype=np.float32),
                "task": task,
            }
        )
    dataset.save_episode()


def read_episode(dataset, episode_index: int) -> dict:
    """One episode of a LeRobotDataset as numpy: ``task``, ``points (F, P, 3)``, ``state (F, 8)``, ``action (F, 8)``
    (float32), its rows read as one numpy slice."""
    episode = dataset.meta.episodes[episode_index]
    columns = [POINTCLOUD_KEY, STATE_KEY, ACTION_KEY]
    rows = dataset.hf_dataset.with_format("numpy", columns=columns)[
        episode["dataset_from_index"] : episode["dataset_to_index"]
    ]
    return {
        "task": episode["tasks"][0],
        **{name: np.asarray(rows[key], dtype=np.float32) for name, key in zip(("points", "state", "action"), columns)},
    }


@contextlib.contextmanager
def keep_array_types_while_aggregating(schema):
    """Let LeRobot's ``aggregate_datasets`` copy 2-D array features such as the point cloud.

    LeRobot 0.6.1 copies data files through pandas and rebuilds the Arrow table without a schema, which fails
    for ``(2048, 3)`` features (nested object arrays). Inside this context its writer is given the shards'
    Arrow ``schema`` (all shards share it), which restores the type and its HF ``Array2D`` metadata.
    """
    import pyarrow as pa
    from lerobot.datasets import aggregate, io_utils

    def write(df, path):
        columns = [_to_arrow(df[field.name], field.type) for field in schema]
        table = pa.Table.from_arrays(columns, schema=schema)
        io_utils.write_table_one_row_group_per_episode(table, path)

    original = aggregate.to_parquet_one_row_group_per_episode
    aggregate.to_parquet_one_row_group_per_episode = write
    try:
        yield
    finally:
        aggregate.to_parquet_one_row_group_per_episode = original


def _to_arrow(column, arrow_type):
    """One pandas column as an Arrow array of ``arrow_type``; nested lists are rebuilt from a stacked array."""
    import pyarrow as pa

    if isinstance(arrow_type, pa.ExtensionType):
        return pa.ExtensionArray.from_storage(arrow_type, _to_arrow(column, arrow_type.storage_type))
    if not pa.types.is_list(arrow_type) or not pa.types.is_list(arrow_type.value_type):
        return pa.array(column.to_list(), type=arrow_type)
    stacked = np.stack([np.stack(list(cell)) for cell in column])
    rows, inner, width = stacked.shape
    values = pa.array(stacked.reshape(-1), type=arrow_type.value_type.value_type)
    inner_lists = pa.ListArray.from_arrays(pa.array(np.arange(0, rows * inner * width + 1, width, dtype=np.int32)), values)
    outer = pa.ListArray.from_arrays(pa.array(np.arange(0, rows * inner + 1, inner, dtype=np.int32)), inner_lists)
    return outer.cast(arrow_type)
