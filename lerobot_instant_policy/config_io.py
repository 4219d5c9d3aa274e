"""Reading dataclass configs from JSON files (nested dataclasses included)."""

from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path
from typing import Any, TypeVar

ConfigT = TypeVar("ConfigT")


def config_from_dict(config_type: type[ConfigT], values: dict[str, Any]) -> ConfigT:
    """Build ``config_type`` from ``values``; unknown keys are an error naming the valid ones."""
    hints = typing.get_type_hints(config_type)
    fields = {field.name: field for field in dataclasses.fields(config_type)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"unknown {config_type.__name__} keys {unknown}; valid keys: {sorted(fields)}")
    kwargs = {}
    for name, value in values.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            kwargs[name] = config_from_dict(hint, value)
        elif isinstance(value, list) and typing.get_origin(hint) is list:
            (item_type,) = typing.get_args(hint)
            kwargs[name] = [config_from_dict(item_type, item) if dataclasses.is_dataclass(item_type) else item for item in value]
        elif isinstance(value, list) and typing.get_origin(hint) is tuple:
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return config_type(**kwargs)


def load_config(config_type: type[ConfigT], path: str | Path) -> ConfigT:
    """Read a JSON file into ``config_type``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file {path} does not exist")
    return config_from_dict(config_type, json.loads(path.read_text()))
