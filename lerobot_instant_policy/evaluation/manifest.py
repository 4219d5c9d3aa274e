"""A column's manifest: what one suite run evaluated, cell by cell, so that only comparable columns share a table.

A *cell* is one task × demonstration set of a suite run (``evaluation.suite``): one ``lerobot-eval`` output
directory with its ``eval_info.json`` and ``suite_cell.json``. The suite writes into ``suite_cell.json`` the settings
that decide the cell's result and, under ``"cell"``, what identifies the cell's episodes: the task, the set, the
evaluation seeds, the seed the demonstrations were recorded from and their number, the fingerprint of the demonstration dataset (a
SHA-256 of its data files) and the swap control's source task. A column's manifest is that record for every cell with
each episode's outcome.

Two columns may be joined in a table (and compared episode by episode, ``evaluation.paired``) only when they hold
the same cells with the same evaluation seeds, and, where both read demonstrations recorded from the same source,
the same demonstration datasets (of the same number of demonstrations: a study of N compares sets of the same
seeds and different sizes): :func:`check_joinable` names the first difference.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

from .success_table import EVAL_INFO, find_eval_infos, load_eval_info

CELL_FILE = "suite_cell.json"  # in each runs/<run name>/<task>/set-<s>: the settings and identity of the cell
DEMO_DATA = "data"  # the folder of a LeRobotDataset's frames (parquet files)


class ManifestError(ValueError):
    """Columns that cannot be joined, or a cell without the record that says what it evaluated."""


@dataclass(frozen=True)
class CellOutcome:
    """One cell of a column: its identity (module docstring) and ``successes``, one per episode in seed order."""

    task: str
    demo_set: int
    eval_seeds: tuple[int, ...]
    demo_seed: int | None
    num_demos: int | None
    demo_fingerprint: str | None
    swap_source: str | None
    successes: tuple[bool, ...]

    @property
    def key(self) -> tuple[str, int]:
        return self.task, self.demo_set


def demo_fingerprint(demos: Path) -> str:
    """SHA-256 (hex) of a demonstration dataset's frames: every file under ``demos/data`` by relative path and
    bytes. ``FileNotFoundError`` when there are none."""
    files = sorted(path for path in (demos / DEMO_DATA).rglob("*") if path.is_file())
    if not files:
        raise FileNotFoundError(f"{demos} has no {DEMO_DATA}/ files: not a recorded demonstration dataset")
    digest = hashlib.sha256()
    for path in files:
        digest.update(path.relative_to(demos).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def cell_identity(task: str, demo_set: int, eval_seed: int, episodes: int, demo_seed: int, num_demos: int,
                  demos: Path | None, swap_source: str | None) -> dict:
    """The ``"cell"`` record of ``suite_cell.json`` (JSON-ready): ``demos`` the dataset of ``num_demos``
    demonstrations the policy read, ``None`` for a policy that reads none."""
    return {"task": task, "demo_set": demo_set, "eval_seeds": list(range(eval_seed, eval_seed + episodes)),
            "demo_seed": demo_seed if demos is not None else None,
            "num_demos": num_demos if demos is not None else None,
            "demo_fingerprint": demo_fingerprint(demos) if demos is not None else None, "swap_source": swap_source}


def read_cell(cell_dir: Path) -> tuple[dict, CellOutcome]:
    """The settings recorded in one suite cell directory's ``suite_cell.json`` and its :class:`CellOutcome`;
    ``ManifestError`` when its record is missing or its episodes do not match its seeds."""
    record_path = cell_dir / CELL_FILE
    record = json.loads(record_path.read_text()) if record_path.is_file() else {}
    if "cell" not in record:
        raise ManifestError(f"{cell_dir} has no cell record ({CELL_FILE} with 'cell'): it was not evaluated by "
                            f"lerobot-ip-eval-suite / lerobot-ip-eval-metaworld, or before cells recorded their "
                            f"seeds; resume it with --resume to record them, or join it unchecked (--unchecked)")
    cell = record.pop("cell")
    per_task = load_eval_info(cell_dir / EVAL_INFO)["per_task"]
    successes = tuple(bool(success) for entry in per_task for success in entry["metrics"]["successes"])
    if len(successes) != len(cell["eval_seeds"]):
        raise ManifestError(f"{cell_dir}: {len(successes)} episodes for {len(cell['eval_seeds'])} evaluation seeds")
    return record, CellOutcome(str(cell["task"]), int(cell["demo_set"]), tuple(cell["eval_seeds"]), cell["demo_seed"],
                               cell["num_demos"], cell["demo_fingerprint"], cell["swap_source"], successes)


def column_manifest(run_dir: Path) -> dict:
    """The manifest of the suite run in ``run_dir`` (``OUT/runs/<name>``): the settings its cells share (those that
    differ between cells, if any, are listed per cell) and every cell (JSON-ready)."""
    records, cells = zip(*(read_cell(eval_info.parent) for eval_info in find_eval_infos(run_dir)), strict=True)
    settings = {key: value for key, value in records[0].items() if key != "swap_source"
                and all(record.get(key) == value for record in records)}
    return {"run_dir": str(run_dir), "settings": settings,
            "cells": [{**asdict(cell), "eval_seeds": list(cell.eval_seeds), "successes": list(cell.successes)}
                      for cell in sorted(cells, key=lambda cell: cell.key)]}


def cells_of(manifest: dict) -> dict[tuple[str, int], CellOutcome]:
    """A manifest's cells by ``(task, demo_set)``."""
    cells = [CellOutcome(**{**cell, "eval_seeds": tuple(cell["eval_seeds"]), "successes": tuple(cell["successes"])})
             for cell in manifest["cells"]]
    return {cell.key: cell for cell in cells}


def check_joinable(manifests: dict[str, dict]) -> None:
    """``ManifestError`` naming the first difference unless every column (name → manifest) holds the same cells with
    the same evaluation seeds and, between columns that read demonstrations of the same source, the same
    demonstration seed and, for the same number of demonstrations, the same dataset (module docstring)."""
    cells = {name: cells_of(manifest) for name, manifest in manifests.items()}
    names = list(cells)
    for name in names[1:]:
        if set(cells[names[0]]) != set(cells[name]):
            missing = sorted(set(cells[names[0]]) ^ set(cells[name]))
            raise ManifestError(f"columns {names[0]!r} and {name!r} hold different cells (task, set): {missing[:4]}")
    for key in cells[names[0]]:
        column_cells = {name: cells[name][key] for name in names}
        seeds = {cell.eval_seeds for cell in column_cells.values()}
        if len(seeds) > 1:
            raise ManifestError(f"{key[0]}, set {key[1]}: the columns were evaluated on different seeds "
                                f"({_seed_spans(column_cells)}); evaluate them on the same split and seeds")
        with_demos = {name: cell for name, cell in column_cells.items() if cell.demo_fingerprint is not None}
        for source, num_demos in {(cell.swap_source, cell.num_demos) for cell in with_demos.values()}:
            same_source = {name: cell for name, cell in with_demos.items()
                           if cell.swap_source == source and cell.num_demos == num_demos}
            if len({(cell.demo_seed, cell.demo_fingerprint) for cell in same_source.values()}) > 1:
                raise ManifestError(f"{key[0]}, set {key[1]}: columns {sorted(same_source)} read different "
                                    f"demonstration sets (seeds {sorted({c.demo_seed for c in same_source.values()})}"
                                    f", or the same seeds recorded differently); evaluate them with the same sets")


def _seed_spans(cells: dict[str, CellOutcome]) -> str:
    return ", ".join(f"{name}: {cell.eval_seeds[0]}…{cell.eval_seeds[-1]}" for name, cell in cells.items())
