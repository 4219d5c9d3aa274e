"""The generation presets of the pseudo-task families' rungs (``workbench/configs/generate/``: the fixed sets the
checkpoint shipped before was trained on, the journal's earlier held-out sets, the in-context learning test's) load
and validate, and none of them lies among the user-facing configs."""

from __future__ import annotations

from pathlib import Path

import pytest

from lerobot_instant_policy.config_io import load_config
from lerobot_instant_policy.pseudo_demos.generation import GenerationConfig

REPO = Path(__file__).resolve().parents[2]
LADDER = REPO / "workbench" / "configs" / "generate"
#: The user-facing configs, which hold no rung's training preset.
SHARED = REPO / "configs" / "generate"


@pytest.mark.parametrize("path", sorted(LADDER.glob("*.json")), ids=lambda path: path.name)
def test_the_ladder_configs_load_and_validate(path):
    config = load_config(GenerationConfig, path)
    config.validate()
    assert config.demo.num_points == 2048 and path.name.startswith("rung")


def test_no_rung_preset_lies_among_the_user_facing_configs():
    assert sorted(LADDER.glob("rung*_train.json"))
    assert not sorted(SHARED.glob("rung*_train.json"))
