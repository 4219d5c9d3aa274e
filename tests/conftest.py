"""Shared test fixtures, and the torch threads of a pytest-xdist worker."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
import torch

from lerobot_instant_policy.objects.rendering import PointCloudRenderer

HELD_OUT_CONFIG = Path(__file__).resolve().parents[1] / "configs" / "generate" / "rung4_full_shared_bounded_val.json"
HELD_OUT_TASKS, HELD_OUT_DEMOS, HELD_OUT_SEED = 4, 3, 321


def pytest_configure(config):
    """Under ``pytest -n W`` each of the W workers gets its share of the cores, for torch here and (through
    ``OMP_NUM_THREADS``) for the processes a test starts: W workers of all cores each would oversubscribe them."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    if workers > 1:
        threads = max(1, (os.cpu_count() or 1) // workers)
        os.environ["OMP_NUM_THREADS"] = str(threads)
        torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def renderer():
    """One pybullet DIRECT renderer shared by every test that only needs to render."""
    with PointCloudRenderer() as shared:
        yield shared


@pytest.fixture(scope="module")
def single_torch_thread():
    """One intra-op torch thread for a module: small models run several times faster on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def held_out_pseudo_tasks(tmp_path_factory) -> Path:
    """The root (its name ``val``: repo id ``local/val``) of fresh pseudo-tasks made as the shipped checkpoint's
    held-out set is (``configs/generate/rung4_full_shared_bounded_val.json``: the full generator, held-out objects,
    bounded turns, one object layout per task, 4 tasks per object pair): 4 pseudo-tasks (one object pair) × 3
    demonstrations (2 to read, the last live), seed 321. Made once for the session: under pytest-xdist once for all
    workers, by the first to ask, under a file lock in the session's directory they share (test_action_error.py and
    test_shipped_checkpoint.py read it)."""
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
