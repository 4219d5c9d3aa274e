"""Fixtures shared by the package's tests (tests/) and the workbench's (workbench/tests/)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

# each test file's seconds in a measured run (setup, call and teardown summed), written by `pytest --store-durations`
DURATIONS_FILE = Path(__file__).resolve().parent / "tests" / "durations.json"
HELD_OUT_CONFIG = Path(__file__).resolve().parent / "configs" / "generate" / "val_one_layout.json"
HELD_OUT_TASKS, HELD_OUT_DEMOS, HELD_OUT_SEED = 4, 3, 321
# the pool run's stream: two objects and one task group, every task loading the same two meshes
POOL_RUN_STREAM = {"seed": 5, "object_pool": ["pb/cube", "pb/duck"], "family": "full", "tasks_per_object_group": 1}
POOL_RUN_FLAGS = ["--stream.samples_per_task=2", "--stream.tasks_per_render=1", "--pool", "--pool.min_tasks=1",
                  "--pool.capacity=4", "--policy.type=instant_policy", "--policy.device=cpu",
                  "--policy.push_to_hub=false", "--policy.max_demos=2", "--policy.reencode_action_clouds=false",
                  "--num_workers=0", "--batch_size=2", "--log_freq=1", "--save_freq=2", "--average.decay=0.5",
                  "--steps=4"]


def pytest_addoption(parser):
    parser.addoption("--store-durations", action="store_true",
                     help="write each test file's seconds in this run to tests/durations.json")


def pytest_configure(config):
    if config.getoption("store_durations") and not hasattr(config, "workerinput"):  # the controller, or no xdist
        config.pluginmanager.register(_FileDurations(), "file-durations")


def pytest_collection_modifyitems(config, items):
    """Test files heaviest first, by :data:`DURATIONS_FILE` (files it lacks last, in their own order): under
    ``make test``'s ``--dist loadfile --no-loadscope-reorder`` the workers take the files in this order, longest
    first, so that no worker is left alone with a long file at the end. Within a file the order stays."""
    if DURATIONS_FILE.is_file():
        seconds = json.loads(DURATIONS_FILE.read_text())["files"]
        items.sort(key=lambda item: -seconds.get(item.nodeid.split("::")[0], 0.0))


class _FileDurations:
    """Sums each test file's reported seconds and writes them to :data:`DURATIONS_FILE` at the session's end."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    def pytest_runtest_logreport(self, report):
        file = report.nodeid.split("::")[0]
        self.seconds[file] = self.seconds.get(file, 0.0) + report.duration

    def pytest_sessionfinish(self, session):
        files = dict(sorted(((file, round(s, 1)) for file, s in self.seconds.items()), key=lambda kv: -kv[1]))
        DURATIONS_FILE.write_text(json.dumps({"files": files}, indent=1) + "\n")


def _session_shared(tmp_path_factory) -> Path:
    """The directory every pytest-xdist worker of this session shares (the base temp without xdist)."""
    shared = tmp_path_factory.getbasetemp()
    return shared.parent if os.environ.get("PYTEST_XDIST_WORKER") else shared


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

    shared = _session_shared(tmp_path_factory)
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


@pytest.fixture(scope="session")
def pool_run(tmp_path_factory) -> Path:
    """The folder of a real ``lerobot-ip-train --pool`` run (``POOL_RUN_FLAGS``: 4 steps of batch 2 on the stream of
    ``POOL_RUN_STREAM``, the pool holding at most 4 tasks, a save every 2 steps, the weights' moving average at decay
    0.5): ``run/checkpoints/00000{2,4}`` and the run's log as ``train.log``. Made once for the session, under a file
    lock like :func:`held_out_pseudo_tasks`, for the tests that resume or compact a pool run's save
    (tests/training/test_stream_seam.py, workbench/tests/test_standing.py); they copy what they change and resume
    with ``--output_dir`` of their own, so the shared run is never written to."""
    from filelock import FileLock

    shared = _session_shared(tmp_path_factory)
    folder = shared / "pool_run"
    log = folder / "train.log"  # written last: the run is complete
    with FileLock(str(shared / "pool_run.lock")):
        if not log.is_file():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            (folder / "stream.json").write_text(json.dumps(POOL_RUN_STREAM))
            command = [str(Path(sys.executable).parent / "lerobot-ip-train"),
                       f"--stream.config={folder / 'stream.json'}", *POOL_RUN_FLAGS, f"--output_dir={folder / 'run'}"]
            env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
            run = subprocess.run(command, capture_output=True, text=True, timeout=600, env=env, cwd=folder)
            assert run.returncode == 0, run.stderr[-3000:]
            log.write_text(run.stdout + run.stderr)
    return folder
