"""Shared test fixtures, and the torch threads of a pytest-xdist worker."""

from __future__ import annotations

import os

import pytest
import torch

from lerobot_instant_policy.objects.rendering import PointCloudRenderer


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
