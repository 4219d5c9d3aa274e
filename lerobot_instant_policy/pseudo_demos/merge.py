"""Merging shard datasets into one LeRobotDataset: LeRobot's serial aggregation and a parallel equivalent.

``merge_serial`` is the reference: LeRobot's ``aggregate_datasets(..., concatenate_data=False)``, which visits the
shards one after another and, for each data file, reads it, shifts ``index`` / ``episode_index`` / ``task_index``
and writes it again as the next ``data/chunk-XXX/file-YYY.parquet``. That rewrite is nearly all of its time.

``merge_parallel`` writes the same dataset with the rewrite spread over worker processes. Everything a data file
needs is known from the shards' metadata alone: the destination ``(chunk, file)`` of the g-th source file (in shard
order, then ``(chunk, file)`` order) is the g-th file of LeRobot's rotation (``update_chunk_file_indices`` from
``(0, 0)``), a shard's episode and frame offsets are the totals of the shards before it, and task indices are
remapped onto the union of tasks in shard order. So the data files are rewritten in a process pool while the main
process writes the metadata with LeRobot's own ``aggregate_metadata`` and ``finalize_aggregation``, given the
offsets and the file mapping that ``aggregate_data`` would have produced. A worker shifts the three index columns
with LeRobot's ``update_data_df`` and keeps every other column as the Arrow data it read, under the first shard's
Arrow schema, so 2-D features such as the ``(P, 3)`` point cloud keep their type (as
``keep_array_types_while_aggregating`` does for the reference) without a round trip through pandas.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

SHIFTED_COLUMNS = ("index", "episode_index", "task_index")


def merge_serial(roots: list[Path], repo_ids: list[str], repo_id: str, root: Path) -> None:
    """LeRobot's ``aggregate_datasets`` of the datasets at ``roots`` (in order) into a new dataset at ``root``."""
    import pyarrow.parquet as pq
    from lerobot.datasets.aggregate import aggregate_datasets

    from ..data.lerobot_format import keep_array_types_while_aggregating

    schema = pq.read_schema(next((Path(roots[0]) / "data").rglob("*.parquet")))
    with keep_array_types_while_aggregating(schema):
        aggregate_datasets(
            repo_ids=list(repo_ids),
            aggr_repo_id=repo_id,
            roots=list(roots),
            aggr_root=root,
            concatenate_data=False,
        )


@dataclass(frozen=True)
class DataFileJob:
    """Rewrite one source data file as one destination data file of the merged dataset.

    ``episode_offset`` / ``frame_offset``: episodes and frames of the shards before this one (added to
    ``episode_index`` and ``index``); ``source_tasks`` / ``tasks``: the shard's and the merged dataset's task tables
    (``task`` index, ``task_index`` column), which remap ``task_index``; ``schema_file``: the parquet file whose Arrow
    schema is written (the schema itself is not passed: pickling a schema renames nested list fields).
    """

    source: Path
    destination: Path
    episode_offset: int
    frame_offset: int
    source_tasks: object
    tasks: object
    schema_file: Path


def rewrite_data_file(job: DataFileJob) -> Path:
    """Write ``job.destination``: the source file's rows with ``index``, ``episode_index`` and ``task_index`` shifted
    by LeRobot's ``update_data_df``, every other column unchanged, one row group per episode."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from lerobot.datasets.aggregate import update_data_df
    from lerobot.datasets.io_utils import write_table_one_row_group_per_episode

    table = pq.read_table(job.source)
    schema = pq.read_schema(job.schema_file)
    source_meta = SimpleNamespace(tasks=job.source_tasks)
    destination_meta = SimpleNamespace(
        tasks=job.tasks, info=SimpleNamespace(total_episodes=job.episode_offset, total_frames=job.frame_offset)
    )
    shifted = update_data_df(table.select(list(SHIFTED_COLUMNS)).to_pandas(), source_meta, destination_meta)
    columns = [
        pa.array(shifted[field.name].to_numpy(), type=field.type) if field.name in SHIFTED_COLUMNS
        else table.column(field.name)
        for field in schema
    ]
    job.destination.parent.mkdir(parents=True, exist_ok=True)
    write_table_one_row_group_per_episode(pa.Table.from_arrays(columns, schema=schema), job.destination)
    return job.destination


def merge_parallel(roots: list[Path], repo_ids: list[str], repo_id: str, root: Path, pool=None) -> None:
    """The dataset ``merge_serial`` writes, with the data files rewritten by the processes of ``pool`` (a
    ``multiprocessing`` pool, e.g. the one that rendered the shards) while this process writes the metadata; without a
    pool, all in this process. Datasets with images or videos are refused (pseudo-demonstrations have none)."""
    import pandas as pd
    from lerobot.datasets.aggregate import (
        aggregate_metadata,
        finalize_aggregation,
        merge_video_feature_info_for_aggregate,
        validate_all_metadata,
    )
    from lerobot.datasets.dataset_metadata import LeRobotDatasetMetadata
    from lerobot.datasets.utils import DEFAULT_DATA_PATH, update_chunk_file_indices

    sources = [LeRobotDatasetMetadata(name, root=path) for name, path in zip(repo_ids, roots, strict=True)]
    fps, robot_type, _ = validate_all_metadata(sources)
    features = merge_video_feature_info_for_aggregate(sources)
    merged = LeRobotDatasetMetadata.create(
        repo_id=repo_id, fps=fps, robot_type=robot_type, features=features, root=root, use_videos=False
    )
    if merged.video_keys or merged.image_keys:
        raise ValueError("merge_parallel handles datasets without images or videos; use merge_serial")
    unique_tasks = pd.concat([source.tasks for source in sources]).index.unique()
    merged.tasks = pd.DataFrame({"task_index": range(len(unique_tasks))}, index=pd.Index(unique_tasks, name="task"))
    merged.episodes = {}
    schema_file = next((Path(roots[0]) / "data").rglob("*.parquet"))

    jobs, file_maps, destination = [], [], None
    episode_offset = frame_offset = 0
    for source in sources:
        source_files = sorted(set(zip(source.episodes["data/chunk_index"], source.episodes["data/file_index"], strict=True)))
        file_map = {}
        for chunk, file in source_files:
            destination = (0, 0) if destination is None else update_chunk_file_indices(*destination, merged.chunks_size)
            file_map[(chunk, file)] = destination
            jobs.append(DataFileJob(
                source=source.root / DEFAULT_DATA_PATH.format(chunk_index=chunk, file_index=file),
                destination=root / DEFAULT_DATA_PATH.format(chunk_index=destination[0], file_index=destination[1]),
                episode_offset=episode_offset, frame_offset=frame_offset,
                source_tasks=source.tasks, tasks=merged.tasks, schema_file=schema_file,
            ))
        file_maps.append((episode_offset, frame_offset, destination, file_map))
        episode_offset += source.total_episodes
        frame_offset += source.total_frames

    def write_metadata() -> None:
        meta_index = {"chunk": 0, "file": 0}
        for source, (episodes_before, frames_before, last_file, file_map) in zip(sources, file_maps, strict=True):
            merged.info.total_episodes, merged.info.total_frames = episodes_before, frames_before
            data_index = {"chunk": last_file[0], "file": last_file[1], "src_to_dst": file_map}
            meta_index = aggregate_metadata(source, merged, meta_index, data_index, {})
        finalize_aggregation(merged, sources)

    if pool is None:
        for job in jobs:
            rewrite_data_file(job)
        write_metadata()
        return
    rewritten = pool.map_async(rewrite_data_file, jobs, chunksize=1)
    write_metadata()
    rewritten.get()
