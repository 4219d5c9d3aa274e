"""The pseudo-task ladder's generation presets (``workbench/configs/generate/``, ``make ladder RUNG=…``) load and
validate, and every rung ``make ladder`` names finds its training and held-out configs."""

from __future__ import annotations

import re
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


def test_every_rung_of_make_ladder_has_its_configs():
    makefile = (REPO / "Makefile").read_text().replace("\\\n", " ")
    names = re.search(r"^RUNG_NAMES = (.*)$", makefile, re.MULTILINE).group(1).split()
    assert len(names) >= 9
    for entry in names:
        name = entry.split(":", 1)[1]
        assert (LADDER / f"{name}_train.json").is_file(), name
        assert (LADDER / f"{name}_val.json").is_file(), name
    assert not sorted(SHARED.glob("rung*_train.json"))
