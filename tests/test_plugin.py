"""Packaging: LeRobot discovers the plugin, the configs under configs/ load."""

from __future__ import annotations

import importlib.metadata
import sys
from pathlib import Path

import pytest

from lerobot_instant_policy.config_io import config_from_dict, load_config
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig

REPO = Path(__file__).resolve().parents[1]


def test_lerobot_plugin_discovery_imports_the_package(monkeypatch):
    from lerobot.utils.import_utils import register_third_party_plugins

    assert importlib.metadata.distribution("lerobot_policy_instant_policy").metadata["Name"] == "lerobot_policy_instant_policy"
    for name in ("lerobot_policy_instant_policy", "lerobot_instant_policy"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    register_third_party_plugins()
    assert "lerobot_policy_instant_policy" in sys.modules
    assert "lerobot_instant_policy" in sys.modules


@pytest.mark.parametrize("path", sorted((REPO / "configs" / "generate").glob("*.json")), ids=lambda path: path.name)
def test_shipped_generation_configs_load_and_validate(path):
    config = load_config(GenerationConfig, path)
    config.validate()
    assert config.demo.num_points == 2048


def test_config_with_unknown_key_is_refused():
    with pytest.raises(ValueError, match="unknown GenerationConfig keys \\['num_taks'\\]"):
        config_from_dict(GenerationConfig, {"num_taks": 3})
