"""The paper's table 2, right half, measured without a simulator: the offline action error of an ``instant_policy``
checkpoint on held-out pseudo-tasks as K (denoising steps), N (context demonstrations) and L (waypoints per
demonstration) vary one at a time around a default setting (``python -m workbench.cli.action_error_sweep``).

Every setting is the installed probe's (``lerobot-ip-action-error``,
:mod:`lerobot_instant_policy.evaluation.action_error`: the same held-out frames, the same DDIM noise per frame, each
value in the config's ranges), so the rows compare on the same draws; the references (context swap, context gain,
untrained, holding still, per third of the live episodes, per task, and the intervals over tasks of the error over
holding still's and of the context gain) are taken at the default setting, the first row.
"""

from __future__ import annotations

import time
from pathlib import Path

from lerobot_instant_policy.evaluation.action_error import (
    DEFAULT_K,
    DEFAULT_L,
    DEFAULT_N,
    evaluate_setting,
    open_probe,
    references,
)

DEFAULT_KS, DEFAULT_NS, DEFAULT_LS = (1, 2, 4, 8), (1, 2, 3), (2, 5, 10, 15)


def grid(ks: list[int], ns: list[int], ls: list[int], default: tuple[int, int, int]) -> list[tuple[int, int, int]]:
    """(K, N, L) settings varying one parameter at a time around ``default`` (which appears once, first)."""
    k0, n0, l0 = default
    settings = [default] + [(k, n0, l0) for k in ks] + [(k0, n, l0) for n in ns] + [(k0, n0, l) for l in ls]
    return list(dict.fromkeys(settings))


def action_error_sweep(policy_path: str | Path, root: str | Path, tasks: int = 12, frames_per_task: int = 4,
                       seed: int = 0, ks: list[int] = DEFAULT_KS, ns: list[int] = DEFAULT_NS,
                       ls: list[int] = DEFAULT_LS, default: tuple[int, int, int] = (DEFAULT_K, DEFAULT_N, DEFAULT_L),
                       untrained: bool = True, repo_id: str | None = None, device: str = "cpu",
                       samples_per_prediction: int | None = None) -> dict:
    """Action errors of the checkpoint at ``policy_path`` on held-out pseudo-tasks at ``root`` at every setting of
    :func:`grid` (module docstring).

    Returns a JSON-ready dict: ``default``, ``settings`` (one row per (K, N, L), the default first), the references at
    the default setting (``swap``, ``context_gain``, ``untrained`` with ``untrained``, ``hold``, ``phases``,
    ``per_task``, ``intervals``), the dataset and sample description and the wall time. Every setting is checked
    before anything is evaluated; ``ActionErrorError`` / ``EvaluationError`` / ``DemonstrationError`` on bad input.
    """
    start = time.perf_counter()
    default = tuple(default)
    settings = grid(list(ks), list(ns), list(ls), default)
    probe = open_probe(policy_path, root, settings, tasks, frames_per_task, seed, repo_id, device,
                       samples_per_prediction)
    rows = [evaluate_setting(probe.policy, probe.tasks, setting) for setting in settings]
    result = {**probe.description, "default": dict(zip("KNL", default)), "settings": rows,
              **references(probe, rows[0], untrained)}
    result["wall_s"] = round(time.perf_counter() - start, 1)
    return result
