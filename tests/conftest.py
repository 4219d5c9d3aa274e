"""Shared fixtures for the data-generation tests."""

from __future__ import annotations

import pytest

from lerobot_instant_policy.data.rendering import PointCloudRenderer


@pytest.fixture(scope="session")
def renderer():
    """One pybullet DIRECT renderer shared by every test that only needs to render."""
    with PointCloudRenderer() as shared:
        yield shared
