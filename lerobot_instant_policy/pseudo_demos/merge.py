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

``append_datasets`` grows a dataset in place by the episodes of others (``workbench/train_rounds.py`` adds each round's
pseudo-tasks to its training dataset): ``merge_parallel`` of the dataset and the new ones with ``link_first``, so the
dataset's own data files are hard-linked unchanged (their offsets are zero and their task indices stay; a rewrite would
give the same bytes) and only the new datasets' files are rewritten. The merge is staged in ``ROOT/.append`` and swapped
into place (``data/``, ``meta/``) once complete; other entries of ``ROOT`` (such as the frame-encoding cache) are left
alone. The old frames keep their data files byte for byte and their ``index`` values, the new ones follow them, which is
what lets ``frame_encodings`` extend its cache instead of rebuilding it.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

SHIFTED_COLUMNS = ("index", "episode_index", "task_index")
APPEND_DIR = ".append"
APPEND_COMPLETE = "COMPLETE"


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
    schema is written (the schema itself is not passed: pickling a schema renames nested list fields); ``link``: the
    destination is the source unchanged (no offsets, the same task indices): hard-link it (copy it across file
    systems) instead of rewriting it.
    """

    source: Path
    destination: Path
    episode_offset: int
    frame_offset: int
    source_tasks: object
    tasks: object
    schema_file: Path
    link: bool = False


def rewrite_data_file(job: DataFileJob) -> Path:
    """Write ``job.destination``: the source file's rows with ``index``, ``episode_index`` and ``task_index`` shifted
    by LeRobot's ``update_data_df``, every other column unchanged, one row group per episode (or, with ``job.link``,
    the source file itself)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from lerobot.datasets.aggregate import update_data_df
    from lerobot.datasets.io_utils import write_table_one_row_group_per_episode

    if job.link:
        job.destination.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(job.source, job.destination)
        except OSError:
            shutil.copyfile(job.source, job.destination)
        return job.destination
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


def merge_parallel(roots: list[Path], repo_ids: list[str], repo_id: str, root: Path, pool=None,
                   link_first: bool = False) -> None:
    """The dataset ``merge_serial`` writes, with the data files rewritten by the processes of ``pool`` (a
    ``multiprocessing`` pool, e.g. the one that rendered the shards) while this process writes the metadata; without a
    pool, all in this process. Datasets with images or videos are refused (pseudo-demonstrations have none).

    ``link_first``: hard-link the first dataset's data files instead of rewriting them wherever the rewrite would
    change nothing but the bytes' layout: the file keeps its ``(chunk, file)`` place and its tasks keep their indices
    (its episode and frame offsets are zero). For a dataset this function wrote, the rewrite gives the same bytes."""
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
    for number, source in enumerate(sources):
        source_files = sorted(set(zip(source.episodes["data/chunk_index"], source.episodes["data/file_index"], strict=True)))
        link_source = link_first and number == 0 and bool((
            merged.tasks.loc[source.tasks.index, "task_index"].to_numpy() == source.tasks["task_index"].to_numpy()
        ).all())
        file_map = {}
        for chunk, file in source_files:
            destination = (0, 0) if destination is None else update_chunk_file_indices(*destination, merged.chunks_size)
            file_map[(chunk, file)] = destination
            jobs.append(DataFileJob(
                source=source.root / DEFAULT_DATA_PATH.format(chunk_index=chunk, file_index=file),
                destination=root / DEFAULT_DATA_PATH.format(chunk_index=destination[0], file_index=destination[1]),
                episode_offset=episode_offset, frame_offset=frame_offset,
                source_tasks=source.tasks, tasks=merged.tasks, schema_file=schema_file,
                link=link_source and destination == (chunk, file),
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


def append_datasets(root: Path, repo_id: str, new_roots: list[Path], new_repo_ids: list[str],
                    meta_files: tuple[str, ...] = ()) -> Path:
    """Grow the dataset at ``root`` (created when it holds none) by the episodes of the datasets at ``new_roots``, in
    order: :func:`prepare_append`, then :func:`finish_append` (after finishing an append an interruption left)."""
    finish_append(root)
    prepare_append(root, repo_id, new_roots, new_repo_ids, meta_files)
    finish_append(root)
    return Path(root)


def prepare_append(root: Path, repo_id: str, new_roots: list[Path], new_repo_ids: list[str],
                   meta_files: tuple[str, ...] = ()) -> Path:
    """Write ``ROOT/.append``: the merge of the dataset at ``root`` (if any) and those at ``new_roots`` by
    ``merge_parallel(..., link_first=True)``, with each of ``meta_files`` (e.g. ``pseudo_tasks.jsonl``) the
    concatenation of the sources' ``meta/<name>``, marked complete last. Only the new datasets' data files are
    written (in this process); the dataset at ``root`` is only read, so this may run while another process trains on
    it. :func:`finish_append` puts the result in place."""
    root, staging = Path(root), Path(root) / APPEND_DIR
    if not new_roots:
        raise ValueError("an append needs at least one dataset to append")
    if (staging / APPEND_COMPLETE).exists():
        raise FileExistsError(f"{staging} holds a finished append that is not in place yet: call finish_append first")
    if staging.exists():
        shutil.rmtree(staging)
    existing = (root / "meta" / "info.json").is_file()
    roots = ([root] if existing else []) + [Path(path) for path in new_roots]
    repo_ids = ([repo_id] if existing else []) + list(new_repo_ids)
    merge_parallel(roots, repo_ids, repo_id, staging, link_first=True)
    for name in meta_files:
        (staging / "meta" / name).write_text("".join((path / "meta" / name).read_text() for path in roots))
    (staging / APPEND_COMPLETE).touch()
    return staging


def finish_append(root: Path) -> bool:
    """Swap a complete ``ROOT/.append`` into place (its ``data/`` and ``meta/`` replace ``ROOT``'s) and return True;
    delete an incomplete one and return False. Safe to run again after an interruption: the old data files stay
    hard-linked in the staged ``data/`` until it is in place."""
    root, staging = Path(root), Path(root) / APPEND_DIR
    if not staging.exists():
        return False
    if not (staging / APPEND_COMPLETE).exists():
        shutil.rmtree(staging)
        return False
    for name in ("data", "meta"):
        if (staging / name).exists():
            if (root / name).exists():
                shutil.rmtree(root / name)
            (staging / name).rename(root / name)
    shutil.rmtree(staging)
    return True
