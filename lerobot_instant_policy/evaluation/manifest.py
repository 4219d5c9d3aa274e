"""A column's manifest: what one suite run evaluated, cell by cell, so that only comparable columns share a table.

A *cell* is one task × demonstration set of a suite run (``evaluation.suite``): one ``lerobot-eval`` output
directory with its ``eval_info.json`` and ``suite_cell.json``. The suite writes into ``suite_cell.json`` the settings
that decide the cell's result; under ``"cell"``, what identifies the cell's episodes: the task, the set, the
evaluation seeds, the seed the demonstrations were recorded from and their number, the fingerprint of the
demonstration dataset (a SHA-256 of its data files) and the swap control's source task; under ``"conditions"``,
every setting that changes an outcome, resolved for the cell (``CONDITIONS``: the checkpoint's SHA-256, the policy
options, the success criterion and its hold steps, the step limit, the env arguments such as sensor noise, the video
size, …). The episodes' seeds are read from ``eval_info.json`` where ``lerobot-eval`` reported them
(``evaluation.lerobot_eval_seeds``) and must be the suite's (``seeds_reported``: true). A column's manifest is that
record for every cell with each episode's outcome.

Two columns may be joined in a table (and compared episode by episode, ``evaluation.paired``) only when they hold
the same cells with the same evaluation seeds, where both read demonstrations recorded from the same source the
same demonstration datasets (of the same number of demonstrations: a study of N compares sets of the same seeds and
different sizes), and the same ``CONDITIONS`` unless a difference is named as allowed (the checkpoint is compared
between columns that load one, the policy options between columns of the same policy): :func:`check_joinable` names
the first difference. A manifest written before a field was recorded lacks it: that field is unknown for its
cells, not checked, and :func:`check_joinable` says so.

A column of a manifest file can be *amended* by a suite run that evaluated some of its cells again (a task whose
success criterion changed): :func:`amend_column` puts the run's cells in place of the column's cells of the same
task × demonstration set and keeps every other one, where the run holds no cell the column lacks, ran each cell on
the column's evaluation seeds and from the same swap source, and was evaluated under the column's settings and
``CONDITIONS`` (but a difference named as allowed). Demonstrations recorded again (another fingerprint) are allowed
and noted. The amended manifest names each replaced cell and the run it came from (``"replaced_cells"``).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

from .success_table import EVAL_INFO, SuccessCount, find_eval_infos, load_eval_info

CELL_FILE = "suite_cell.json"  # in each runs/<run name>/<task>/set-<s>: the settings and identity of the cell
DEMO_DATA = "data"  # the folder of a LeRobotDataset's frames (parquet files)
MANIFEST_SUFFIX = ".manifest.json"  # lerobot-ip-eval-table's OUT.manifest.json: {column: manifest}
# What changes a cell's outcome besides its identity: the name --allow-difference takes → the key of a cell's
# "conditions" record and what it holds.
CONDITIONS = {
    "checkpoint": ("checkpoint_sha256", "the SHA-256 of the checkpoint's files (compared between columns that load "
                                        "one)"),
    "policy_options": ("policy_options", "the --policy.KEY=VALUE overrides (compared between columns of the same "
                                         "policy)"),
    "language_head": ("language_head_sha256", "the SHA-256 of the language head's files (compared between columns "
                                              "that say tasks in words)"),
    "success": ("success", "the success criterion (held, instant, or MetaWorld's own flag)"),
    "hold_steps": ("hold_steps", "the steps the goal state must hold"),
    "episode_length": ("episode_length", "the step limit of an episode"),
    "env_args": ("env_args", "the --env.KEY=VALUE settings but the video size: sensor noise, calibration error, …"),
    "render_size": ("render_size", "the size of the video frames"),
    "obs_type": ("obs_type", "the observation path (bullet_tabletop: pointcloud or rgbd)"),
    "pointcloud_every": ("pointcloud_every", "how often the cloud is rendered (MetaWorld)"),
}
# The settings of a cell record (suite_cell.json without "cell" and "conditions") that hold a condition, for cells
# recorded before their "conditions" were.
SETTING_CONDITIONS = {"policy_args": "policy_options", "success": "success", "env_args": "env_args",
                      "obs_type": "obs_type", "episode_length": "episode_length",
                      "pointcloud_every": "pointcloud_every"}
# The settings that hold a condition, by the name --allow-difference takes: an amending run (amend_column) may differ
# from its column in those named.
SETTING_ALLOWANCES = {**SETTING_CONDITIONS, "policy_path": "checkpoint"}
CHECKPOINT_SKIPPED = ("README.md", "train_config.json")  # a checkpoint's model card and training record
LANGUAGE_CONTEXT_ARG = "--policy.context=language"  # instant_policy reads the env's task in words instead


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
    seeds_reported: bool | None = None  # True: lerobot-eval reported eval_seeds; False: it reported none; None: unknown
    demonstrator: str = "gripper"  # who recorded the demonstrations: the scripted gripper, or a (simulated) hand

    @property
    def key(self) -> tuple[str, int]:
        return self.task, self.demo_set


def _files_digest(root: Path, files: list[Path]) -> str:
    """SHA-256 (hex) of ``files`` under ``root``, in order: each one's relative path, a NUL, then its bytes."""
    digest = hashlib.sha256()
    for path in files:
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def demo_fingerprint(demos: Path) -> str:
    """SHA-256 (hex) of a demonstration dataset's frames: every file under ``demos/data`` by relative path and
    bytes. ``FileNotFoundError`` when there are none."""
    files = sorted(path for path in (demos / DEMO_DATA).rglob("*") if path.is_file())
    if not files:
        raise FileNotFoundError(f"{demos} has no {DEMO_DATA}/ files: not a recorded demonstration dataset")
    return _files_digest(demos, files)


def checkpoint_fingerprint(checkpoint: Path) -> str:
    """SHA-256 (hex) of a pretrained_model directory, or of a language head's: every file by relative path and bytes
    but the model card and the training record (``CHECKPOINT_SKIPPED``), which no evaluation reads.
    ``FileNotFoundError`` when it holds no file."""
    files = sorted(path for path in checkpoint.rglob("*") if path.is_file() and path.name not in CHECKPOINT_SKIPPED)
    if not files:
        raise FileNotFoundError(f"{checkpoint} holds no checkpoint files")
    return _files_digest(checkpoint, files)


def cell_identity(task: str, demo_set: int, eval_seed: int, episodes: int, demo_seed: int, num_demos: int,
                  demos: Path | None, swap_source: str | None) -> dict:
    """The ``"cell"`` record of ``suite_cell.json`` (JSON-ready): ``demos`` the dataset of ``num_demos``
    demonstrations the policy read, ``None`` for a policy that reads none."""
    return {"task": task, "demo_set": demo_set, "eval_seeds": list(range(eval_seed, eval_seed + episodes)),
            "demo_seed": demo_seed if demos is not None else None,
            "num_demos": num_demos if demos is not None else None,
            "demo_fingerprint": demo_fingerprint(demos) if demos is not None else None, "swap_source": swap_source}


def reported_seeds(per_task: list[dict]) -> tuple | None:
    """The seed of every episode of an ``eval_info.json``'s ``per_task`` entries, in order, as ``lerobot-eval``
    reported them (``metrics.seeds``, ``evaluation.lerobot_eval_seeds``); ``None`` when an entry has none."""
    if not per_task or any(not isinstance(entry["metrics"].get("seeds"), list) for entry in per_task):
        return None
    return tuple(seed for entry in per_task for seed in entry["metrics"]["seeds"])


def read_cell(cell_dir: Path) -> tuple[dict, CellOutcome]:
    """The settings recorded in one suite cell directory's ``suite_cell.json`` (with its ``"conditions"`` record,
    if any) and its :class:`CellOutcome`; ``ManifestError`` when its record is missing, its episodes do not match
    its seeds, or ``lerobot-eval`` reports other seeds than the cell's."""
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
    seeds = reported_seeds(per_task)
    if seeds is not None and list(seeds) != list(cell["eval_seeds"]):
        raise ManifestError(f"{cell_dir}: lerobot-eval ran seeds {_span(seeds)}, the cell records "
                            f"{_span(cell['eval_seeds'])}")
    return record, CellOutcome(str(cell["task"]), int(cell["demo_set"]), tuple(cell["eval_seeds"]), cell["demo_seed"],
                               cell["num_demos"], cell["demo_fingerprint"], cell["swap_source"], successes,
                               seeds is not None, record.get("demonstrator", "gripper"))


def _span(seeds) -> str:
    return f"{seeds[0]}…{seeds[-1]}" if seeds else "none"


def column_manifest(run_dir: Path) -> dict:
    """The manifest of the suite run in ``run_dir`` (``OUT/runs/<name>``): the settings its cells share and every
    cell (JSON-ready) with its ``"conditions"`` record (absent for a cell recorded before them)."""
    read = [read_cell(eval_info.parent) for eval_info in find_eval_infos(run_dir)]
    records = [{key: value for key, value in record.items() if key != "conditions"} for record, _ in read]
    settings = {key: value for key, value in records[0].items() if key != "swap_source"
                and all(record.get(key) == value for record in records)}
    cells = []
    for record, cell in sorted(read, key=lambda pair: pair[1].key):
        entry = {**asdict(cell), "eval_seeds": list(cell.eval_seeds), "successes": list(cell.successes)}
        if "conditions" in record:
            entry["conditions"] = record["conditions"]
        cells.append(entry)
    return {"run_dir": str(run_dir), "settings": settings, "cells": cells}


def cells_of(manifest: dict) -> dict[tuple[str, int], CellOutcome]:
    """A manifest's cells by ``(task, demo_set)`` (a field a manifest lacks takes its default: unknown)."""
    fields = CellOutcome.__dataclass_fields__
    demonstrator = manifest["settings"].get("demonstrator", "gripper")
    cells = [CellOutcome(**{"demonstrator": demonstrator,
                            **{key: value for key, value in cell.items() if key in fields},
                            "eval_seeds": tuple(cell["eval_seeds"]), "successes": tuple(cell["successes"])})
             for cell in manifest["cells"]]
    return {cell.key: cell for cell in cells}


def conditions_of(manifest: dict) -> dict[tuple[str, int], dict]:
    """Each cell's ``CONDITIONS`` by ``(task, demo_set)``, keyed by the names ``--allow-difference`` takes: its
    ``"conditions"`` record, else what the column's settings hold (a cell recorded before its conditions were); no
    language head where its policy options do not say tasks in words; a condition neither holds is missing
    (unknown)."""
    settings = manifest["settings"]
    from_settings = {name: settings[key] for key, name in SETTING_CONDITIONS.items() if key in settings}
    if "obs_type" in settings:  # bullet_tabletop's: no MetaWorld setting applies
        from_settings.setdefault("pointcloud_every", None)
    if "pointcloud_every" in settings:  # MetaWorld's: no bullet_tabletop setting applies
        from_settings.setdefault("obs_type", None)
    conditions = {}
    for cell in manifest["cells"]:
        record = cell.get("conditions")
        if record is None:
            known = dict(from_settings)
        else:
            known = {name: record[key] for name, (key, _) in CONDITIONS.items() if key in record}
        options = known.get("policy_options")
        if "language_head" not in known and options is not None and LANGUAGE_CONTEXT_ARG not in options:
            known["language_head"] = None  # recorded before the head was: its options say it read no head
        conditions[(cell["task"], cell["demo_set"])] = known
    return conditions


def unknown_conditions(manifests: dict[str, dict]) -> dict[str, list[str]]:
    """Per column, what its manifest does not record (``CONDITIONS`` names, and ``seeds as run`` where its cells'
    seeds are the suite's and not ``lerobot-eval``'s report): those are not checked."""
    unknown = {}
    for name, manifest in manifests.items():
        conditions = conditions_of(manifest).values()
        missing = [condition for condition in CONDITIONS if any(condition not in cell for cell in conditions)]
        if any(cell.seeds_reported is not True for cell in cells_of(manifest).values()):
            missing.append("seeds as run")
        if missing:
            unknown[name] = missing
    return unknown


def check_joinable(manifests: dict[str, dict], allowed: tuple[str, ...] = ()) -> dict[str, list[str]]:
    """``ManifestError`` naming the first difference unless every column (name → manifest) holds the same cells with
    the same evaluation seeds; between columns that read demonstrations of the same source, the same demonstration
    seed and, for the same number of demonstrations, the same dataset; and the same ``CONDITIONS`` but those named
    in ``allowed`` (module docstring). Returns what each column does not record (:func:`unknown_conditions`)."""
    unknown_names = sorted(set(allowed) - set(CONDITIONS))
    if unknown_names:
        raise ManifestError(f"--allow-difference takes {', '.join(CONDITIONS)}; not {', '.join(unknown_names)}")
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
        for same_source in _same_source_readers(column_cells):
            if len({(cell.demo_seed, cell.demo_fingerprint) for cell in same_source.values()}) > 1:
                raise ManifestError(f"{key[0]}, set {key[1]}: columns {sorted(same_source)} read different "
                                    f"demonstration sets (seeds {sorted({c.demo_seed for c in same_source.values()})}"
                                    f", or the same seeds recorded differently); evaluate them with the same sets")
    check_conditions(manifests, allowed)
    return unknown_conditions(manifests)


def _same_source_readers(column_cells: dict[str, CellOutcome]) -> list[dict[str, CellOutcome]]:
    """One cell's columns (name → cell) that read demonstrations, grouped by what they read: the same source task,
    number of demonstrations and demonstrator (a hand's demonstrations of a seed are not the gripper's)."""
    with_demos = {name: cell for name, cell in column_cells.items() if cell.demo_fingerprint is not None}
    groups = {name: (cell.swap_source, cell.num_demos, cell.demonstrator) for name, cell in with_demos.items()}
    return [{name: with_demos[name] for name, group in groups.items() if group == chosen}
            for chosen in sorted(set(groups.values()), key=str)]


def recorded_differently(manifests: dict[str, dict]) -> list[str]:
    """The tasks (sorted) with a cell whose demonstrations two columns read from the same seed and source but with
    other bytes: the same set recorded on another machine, where the simulator's arithmetic differs (a column
    evaluated elsewhere). Evaluating those tasks of the older column again where the newer one ran, and amending it
    with that run (:func:`amend_column`), pairs the columns on the same demonstrations. Cells some column lacks are
    left out."""
    cells = [cells_of(manifest) for manifest in manifests.values()]
    tasks = set()
    for key in set.intersection(*(set(column) for column in cells)):
        column_cells = dict(zip(manifests, (column[key] for column in cells)))
        for same_source in _same_source_readers(column_cells):
            for seed in {cell.demo_seed for cell in same_source.values()}:
                if len({cell.demo_fingerprint for cell in same_source.values() if cell.demo_seed == seed}) > 1:
                    tasks.add(key[0])
    return sorted(tasks)


def check_conditions(manifests: dict[str, dict], allowed: tuple[str, ...] = ()) -> None:
    """``ManifestError`` naming the first cell and ``CONDITIONS`` name whose known values differ between columns
    (the checkpoint between columns that load one, the policy options between columns of the same policy), unless
    that name is in ``allowed``."""
    conditions = {name: conditions_of(manifest) for name, manifest in manifests.items()}
    policies = {name: manifest["settings"].get("policy") for name, manifest in manifests.items()}
    names = list(manifests)
    for key in sorted(conditions[names[0]]):
        for condition in CONDITIONS:
            if condition in allowed:
                continue
            known = {name: conditions[name][key][condition] for name in names if condition in conditions[name][key]}
            if condition in ("checkpoint", "language_head"):
                scopes = [{name: value for name, value in known.items() if value is not None}]
            elif condition == "policy_options":
                scopes = [{name: value for name, value in known.items() if policies[name] == policy}
                          for policy in sorted({policies[name] for name in known}, key=str)]
            else:
                scopes = [known]
            for scope in scopes:
                if len({json.dumps(value, sort_keys=True) for value in scope.values()}) > 1:
                    values = "; ".join(f"{name}: {value}" for name, value in scope.items())
                    raise ManifestError(f"{key[0]}, set {key[1]}: the columns differ in {condition} "
                                        f"({CONDITIONS[condition][1]}): {values}. Evaluate them under the same "
                                        f"{condition}, or name the difference with --allow-difference {condition}")


def read_manifest_file(path: Path, column: str | None = None) -> dict[str, dict]:
    """The columns of a manifest file lerobot-ip-eval-table wrote (``OUT.manifest.json``: column → manifest), only
    ``column`` when given; ``ManifestError`` when it is no such file or lacks ``column``."""
    try:
        manifests = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ManifestError(f"{path} is not valid JSON: {error}") from error
    if not isinstance(manifests, dict) or not manifests or not all(
            isinstance(manifest, dict) and isinstance(manifest.get("settings"), dict)
            and isinstance(manifest.get("cells"), list) for manifest in manifests.values()):
        raise ManifestError(f"{path} is not a manifest file (lerobot-ip-eval-table's OUT{MANIFEST_SUFFIX}: each "
                            f"column's 'settings' and 'cells')")
    if column is None:
        return manifests
    if column not in manifests:
        raise ManifestError(f"{path} has no column {column!r} (it holds {', '.join(manifests)})")
    return {column: manifests[column]}


def amend_column(column: str, manifest: dict, run_dir: Path, allowed: tuple[str, ...] = ()) -> tuple[dict, list[str]]:
    """Column ``column``'s ``manifest`` with the cells of the suite run in ``run_dir`` (:func:`column_manifest`) in
    place of its own of the same (task, demonstration set), and the notes to print (what was replaced, demonstrations
    recorded again); its ``"replaced_cells"`` lists every cell replaced so far, each ``{"task", "demo_set", "from":
    run dir}``. ``ManifestError`` when the run holds a cell the column lacks, ran a cell on other seeds or from
    another swap source, or differs from the column in a setting or ``CONDITIONS`` but those named in ``allowed``
    (module docstring)."""
    run = column_manifest(run_dir)
    ours, theirs = cells_of(manifest), cells_of(run)
    added = sorted(set(theirs) - set(ours))
    if added:
        raise ManifestError(f"{run_dir} holds cells (task, set) that column {column!r} lacks: {added[:4]}; a run "
                            f"replaces cells of the column it follows, it adds none")
    notes = [f"{column}: the cells of {', '.join(sorted({task for task, _ in theirs}))} ({len(theirs)} of "
             f"{len(ours)}) replaced by those of {run_dir}"]
    for key in sorted(theirs):
        if theirs[key].eval_seeds != ours[key].eval_seeds:
            raise ManifestError(f"{key[0]}, set {key[1]}: {run_dir} ran seeds {_span(theirs[key].eval_seeds)}, "
                                f"column {column!r} {_span(ours[key].eval_seeds)}; evaluate it on the column's seeds")
        if theirs[key].swap_source != ours[key].swap_source:
            raise ManifestError(f"{key[0]}, set {key[1]}: {run_dir} read {theirs[key].swap_source}'s "
                                f"demonstrations, column {column!r} {ours[key].swap_source}'s")
        if theirs[key].demo_fingerprint != ours[key].demo_fingerprint:
            notes.append(f"{column}: {key[0]}, set {key[1]} from {run_dir}: its demonstrations were recorded again "
                         f"(another fingerprint than the manifest's)")
    settings, run_settings = manifest["settings"], run["settings"]
    changed = sorted(key for key in settings.keys() | run_settings.keys() if settings.get(key) != run_settings.get(key)
                     and SETTING_ALLOWANCES.get(key) not in allowed)
    if changed:
        values = "; ".join(f"{key}: {settings.get(key)} in the column, {run_settings.get(key)} in the run"
                           for key in changed)
        nameable = sorted({SETTING_ALLOWANCES[key] for key in changed if key in SETTING_ALLOWANCES})
        hint = "".join(f" --allow-difference {name}" for name in nameable)
        raise ManifestError(f"{run_dir} was evaluated with other settings than column {column!r} ({values}); "
                            f"evaluate it with the column's" + (f", or name the difference with{hint}" if hint else ""))
    replaced = {(cell["task"], cell["demo_set"]): cell for cell in run["cells"]}
    check_conditions({column: {**manifest, "cells": [cell for cell in manifest["cells"]
                                                     if (cell["task"], cell["demo_set"]) in replaced]},
                      f"{column} from {run_dir}": run}, allowed)
    records = [record for record in manifest.get("replaced_cells", [])
               if (record["task"], record["demo_set"]) not in replaced]
    records += [{"task": task, "demo_set": demo_set, "from": str(run_dir)} for task, demo_set in sorted(replaced)]
    cells = [replaced.get((cell["task"], cell["demo_set"]), cell) for cell in manifest["cells"]]
    return {**manifest, "cells": cells, "replaced_cells": records}, notes


def manifest_counts(name: str, manifest: dict) -> list[SuccessCount]:
    """The success counts of column ``name`` per task, each with its cells (``success_table.SuccessCount``)."""
    per_task: dict[str, list] = {}
    for cell in cells_of(manifest).values():
        counts = per_task.setdefault(cell.task, [0, 0, ()])
        counts[0] += len(cell.successes)
        counts[1] += sum(cell.successes)
        counts[2] += ((cell.task, sum(cell.successes), len(cell.successes)),)
    return [SuccessCount(task, name, episodes, successes, cells)
            for task, (episodes, successes, cells) in per_task.items()]


def _seed_spans(cells: dict[str, CellOutcome]) -> str:
    return ", ".join(f"{name}: {cell.eval_seeds[0]}…{cell.eval_seeds[-1]}" for name, cell in cells.items())
