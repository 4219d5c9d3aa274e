"""Older ``instant_policy`` config files: the options they name that the config no longer has, dropped at load time.

Four options were removed, each with the one behaviour the model kept: ``flow_loss_weighting`` (the flow losses
weighted alike over the timesteps, ``"uniform"``), ``noise_draws`` (one diffusion timestep and noise per training
sample, 1), ``context_scene_edges`` (φ reads no scene nodes, false) and ``dense_attention`` (σ, φ and ψ run in the
dense layout, whose outputs the torch-geometric layout gives too: true or false). Checkpoints written before name
them in ``config.json``, and in the ``policy`` section of ``train_config.json``, mostly as ``null``.

:func:`migrate` drops them: ``null`` or a value the model still has is dropped (the latter with a warning), any
other value is refused with a ``ValueError`` naming it, since the model it describes no longer exists.

LeRobot reads those files with draccus, which refuses unknown keys and offers a policy config no hook of its own (it
refuses a custom decoder on a policy config, which is a choice type), and it calls the base class's reader
(``PreTrainedConfig.from_pretrained``), never the policy's. So :func:`install`, run when the config module is
imported, wraps LeRobot's two readers, ``PreTrainedConfig.from_pretrained`` (``config.json``: ``lerobot-eval`` and
``lerobot-train --policy.path``, ``from_pretrained``) and ``TrainPipelineConfig.from_pretrained``
(``train_config.json``: ``lerobot-train --resume``): a local file of type ``instant_policy`` that names a removed
option is read through :func:`migrate` from a temporary copy; every other file, and every Hub id, goes to LeRobot
as it is.
"""

from __future__ import annotations

import functools
import json
import logging
import tempfile
from collections.abc import Callable
from pathlib import Path

logger = logging.getLogger(__name__)

POLICY_TYPE = "instant_policy"

# The removed options, each with the values that describe what the model now always does.
RETIRED_OPTIONS: dict[str, tuple] = {
    "flow_loss_weighting": ("uniform",),
    "noise_draws": (1,),
    "context_scene_edges": (False,),
    "dense_attention": (True, False),
}


def migrate(values: dict) -> dict:
    """``values`` (an ``instant_policy`` config as JSON) without the removed options (module docstring)."""
    given = {name: values[name] for name in RETIRED_OPTIONS if values.get(name) is not None}
    refused = {name: value for name, value in given.items() if value not in RETIRED_OPTIONS[name]}
    if refused:
        raise ValueError(
            "instant_policy options that were removed, with values that change the model: "
            + ", ".join(f"{name}={value!r} (only {list(RETIRED_OPTIONS[name])} can load)" for name, value in refused.items())
        )
    if given:
        logger.warning("instant_policy: dropped removed options with the values the model now always has: %s",
                       ", ".join(f"{name}={value!r}" for name, value in given.items()))
    return {key: value for key, value in values.items() if key not in RETIRED_OPTIONS}


def install() -> None:
    """Wrap LeRobot's readers of ``config.json`` and ``train_config.json`` (module docstring); once per process."""
    from huggingface_hub.constants import CONFIG_NAME
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.configs.train import TRAIN_CONFIG_NAME, TrainPipelineConfig

    _wrap_reader(PreTrainedConfig, CONFIG_NAME, lambda values: values, lambda values, policy: policy)
    _wrap_reader(TrainPipelineConfig, TRAIN_CONFIG_NAME, lambda values: values.get("policy"),
                 lambda values, policy: {**values, "policy": policy})


def _wrap_reader(owner: type, file_name: str, policy_of: Callable[[dict], object],
                 with_policy: Callable[[dict, dict], dict]) -> None:
    """Replace ``owner.from_pretrained`` with a reader that hands LeRobot's a migrated copy of the local file
    ``file_name`` (a folder's, or the file itself) where its policy section (``policy_of``) needs :func:`migrate`."""
    read = owner.__dict__["from_pretrained"].__func__
    if getattr(read, "_migrates_instant_policy", False):
        return

    @functools.wraps(read)
    def from_pretrained(cls, pretrained_name_or_path, *args, **kwargs):
        path = Path(pretrained_name_or_path)
        file = path / file_name if path.is_dir() else path
        values = _read_json(file) if file.is_file() else None
        policy = policy_of(values) if isinstance(values, dict) else None
        if not (isinstance(policy, dict) and policy.get("type") == POLICY_TYPE and RETIRED_OPTIONS.keys() & policy.keys()):
            return read(cls, pretrained_name_or_path, *args, **kwargs)
        migrated = with_policy(values, migrate(policy))
        with tempfile.TemporaryDirectory(prefix="instant_policy_config_") as folder:
            (Path(folder) / file_name).write_text(json.dumps(migrated, indent=4))
            return read(cls, folder, *args, **kwargs)

    from_pretrained._migrates_instant_policy = True
    owner.from_pretrained = classmethod(from_pretrained)


def _read_json(file: Path) -> object:
    """The JSON in ``file``, or None where it is not JSON (LeRobot's reader then reports it)."""
    try:
        return json.loads(file.read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return None
