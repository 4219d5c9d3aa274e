"""Checkpoints of ``instant_policy`` runs: finding them in a ``lerobot-train`` output directory and loading them (the
policy, and the preprocessor saved beside it) for offline evaluation (``loss_curve``, ``action_error``, the
benchmarks and ``workbench/scripts``)."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from ..modeling_instant_policy import InstantPolicyPolicy

POLICY_TYPE = "instant_policy"
PREPROCESSOR_FILE = "policy_preprocessor.json"


class EvaluationError(ValueError):
    """A run without checkpoints, a dataset that is not a pseudo-demonstration dataset, a foreign checkpoint, …"""


@dataclass(frozen=True)
class Checkpoint:
    """``path``: a ``pretrained_model`` directory saved by ``lerobot-train`` after ``step`` optimiser steps."""

    step: int
    path: Path


# ---------------------------------------------------------------------------------------------------- checkpoints
def find_checkpoints(run_dir: str | Path) -> list[Checkpoint]:
    """The run's checkpoints in step order (the ``last`` link and unfinished checkpoints without weights skipped)."""
    folder = Path(run_dir) / "checkpoints"
    found = []
    if folder.is_dir():
        for entry in folder.iterdir():
            model = entry / "pretrained_model"
            if entry.is_symlink() or not entry.name.isdigit():
                continue
            if (model / "config.json").is_file() and (model / "model.safetensors").is_file():
                found.append(Checkpoint(int(entry.name), model))
    if not found:
        raise EvaluationError(
            f"no checkpoints found in {run_dir}: expected {folder}/<step>/pretrained_model with config.json and "
            "model.safetensors, as lerobot-train --save_freq writes them"
        )
    return sorted(found, key=lambda checkpoint: checkpoint.step)


def checkpoint_config(checkpoint: Checkpoint):
    """The checkpoint's ``InstantPolicyConfig``; ``EvaluationError`` when it holds another policy type."""
    from lerobot.configs.policies import PreTrainedConfig

    config_file = checkpoint.path / "config.json"
    try:
        policy_type = json.loads(config_file.read_text()).get("type")
    except (OSError, json.JSONDecodeError, AttributeError) as error:
        raise EvaluationError(f"cannot read the policy config {config_file}: {error}") from error
    if policy_type != POLICY_TYPE:
        raise EvaluationError(f"checkpoint {checkpoint.path} is a {policy_type!r} policy, not {POLICY_TYPE!r}")
    return PreTrainedConfig.from_pretrained(checkpoint.path)


def load_policy(path: str | Path, device: str = "cpu", **overrides) -> InstantPolicyPolicy:
    """The ``instant_policy`` checkpoint at ``path`` (a ``pretrained_model`` directory) on ``device``, in eval mode,
    with the config fields in ``overrides`` replaced. LeRobot's "Loading weights …" print goes to stderr, so CLIs
    that print JSON keep stdout clean. ``EvaluationError`` when ``path`` holds another policy type."""
    config = checkpoint_config(Checkpoint(step=0, path=Path(path)))
    config = dataclasses.replace(config, device=device, **overrides)
    with contextlib.redirect_stdout(sys.stderr):
        return InstantPolicyPolicy.from_pretrained(path, config=config).eval()


def load_checkpoint(checkpoint: Checkpoint, device: str = "cpu"):
    """``(policy, preprocessor)`` of a checkpoint on ``device``: the policy in eval mode, the preprocessor that
    ``lerobot-train`` saved beside it (its device step moved to ``device``)."""
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import batch_to_transition, transition_to_batch

    policy = load_policy(checkpoint.path, device)
    if not (checkpoint.path / PREPROCESSOR_FILE).is_file():
        raise EvaluationError(f"checkpoint {checkpoint.path} has no {PREPROCESSOR_FILE}")
    preprocessor = PolicyProcessorPipeline.from_pretrained(
        checkpoint.path,
        config_filename=PREPROCESSOR_FILE,
        overrides={"device_processor": {"device": device}},
        to_transition=batch_to_transition,
        to_output=transition_to_batch,
    )
    return policy, preprocessor


def weights_fingerprint(checkpoint: Checkpoint) -> str:
    """SHA-256 of the checkpoint's ``model.safetensors``."""
    digest = hashlib.sha256()
    with open(checkpoint.path / "model.safetensors", "rb") as handle:
        for block in iter(lambda: handle.read(1 << 22), b""):
            digest.update(block)
    return digest.hexdigest()
