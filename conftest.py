"""Fixtures shared by the package's tests (tests/) and the workbench's (workbench/tests/)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

HELD_OUT_CONFIG = Path(__file__).resolve().parent / "configs" / "generate" / "val_one_layout.json"
HELD_OUT_TASKS, HELD_OUT_DEMOS, HELD_OUT_SEED = 4, 3, 321


@pytest.fixture(scope="session")
def held_out_pseudo_tasks(tmp_path_factory) -> Path:
    """The root (its name ``val``: repo id ``local/val``) of fresh pseudo-tasks made as the shipped checkpoint's
    held-out set is (``configs/generate/val_one_layout.json``: the full generator, held-out objects,
    bounded turns, one object layout per task, 4 tasks per object pair): 4 pseudo-tasks (one object pair) × 3
    demonstrations (2 to read, the last live), seed 321. Made once for the session: under pytest-xdist once for all
    workers, by the first to ask, under a file lock in the session's directory they share (test_action_error.py,
    test_shipped_checkpoint.py and workbench/tests/test_standing.py read it)."""
    from filelock import FileLock

    from lerobot_instant_policy.cli.generate import main as generate_main

    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # this session's directory, above every worker's own
    done, building = shared / "held_out_pseudo_tasks", shared / "held_out_pseudo_tasks.building"
    with FileLock(str(shared / "held_out_pseudo_tasks.lock")):
        if not done.is_dir():
            shutil.rmtree(building, ignore_errors=True)
            assert generate_main(["--config", str(HELD_OUT_CONFIG), "--out", str(building / "val"),
                                  "--repo-id", "local/val", "--num-tasks", str(HELD_OUT_TASKS),
                                  "--demos-per-task", str(HELD_OUT_DEMOS), "--seed", str(HELD_OUT_SEED),
                                  "--workers", "1", "--no-progress"]) == 0
            building.rename(done)
    return done / "val"
