"""Shared test fixtures."""

from __future__ import annotations

import pytest
import torch

from lerobot_instant_policy.objects.rendering import PointCloudRenderer


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
