"""One setting of a benchmark on and off in alternation, in one run: the medians of a figure and their ratio.

Timings drift with the machine's load and temperature; alternating the two variants within one process and taking
medians over rounds makes their ratio the figure to trust, rather than two numbers from two separate runs. The
benchmarks compared are the installed ones (``lerobot-ip-bench inference`` and ``train-step``:
:mod:`lerobot_instant_policy.benchmarks.policy`); ``python -m workbench.cli.bench inference|train-step --compare-*``
is the command line.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable

from lerobot_instant_policy.benchmarks.policy import bench_inference, bench_train_step

#: The settings :func:`inference_comparison` compares, each with the names of its True and False variants.
INFERENCE_COMPARISONS = {"dense_attention": ("dense", "reference"), "compile_inference": ("compiled", "eager")}
#: The settings :func:`train_step_comparison` compares, each with the names of its True and False variants.
TRAIN_STEP_COMPARISONS = {
    "dense_attention": ("dense", "reference"),
    "frame_cache": ("cached", "live"),
    "use_amp": ("amp", "float32"),
    "fused_adamw": ("fused", "loop"),
    "compile_model": ("compiled", "eager"),
}


def compare_variants(run: Callable[..., dict], figure: str, option: str, names: tuple[str, str], rounds: int = 3) -> dict:
    """``run(**{option: True})`` and ``run(**{option: False})`` in alternation, ``rounds`` times each; the medians of
    ``figure`` under ``names`` (for True, for False) and their ratio, measured in this one run."""
    results = {True: [], False: []}
    for _ in range(rounds):
        for value in (True, False):
            results[value].append(run(**{option: value}))
    on, off = (statistics.median(result[figure] for result in results[value]) for value in (True, False))
    return {
        **{key: value for key, value in results[True][0].items()
           if key not in (figure, option) and not key.startswith("runs")},
        "figure": figure, "rounds": rounds,
        names[0]: on, names[1]: off,
        f"{names[0]}_over_{names[1]}": round(on / off, 3),
        f"runs_{names[0]}": [result[figure] for result in results[True]],
        f"runs_{names[1]}": [result[figure] for result in results[False]],
    }


def run_or_compare(run: Callable[..., dict], figure: str, settings: dict, compare: str | None,
                   comparisons: dict[str, tuple[str, str]]) -> dict:
    """``run(**settings)`` once; or, with ``compare`` (a key of ``comparisons``, which names its True and False
    variants), :func:`compare_variants` of that option with the other ``settings`` held (its own value in
    ``settings``, if any, is left out)."""
    if compare is None:
        return run(**settings)
    if compare not in comparisons:
        raise ValueError(f"cannot compare {compare!r}: choose from {sorted(comparisons)}")
    held = {key: value for key, value in settings.items() if key != compare}
    return compare_variants(lambda **variant: run(**held, **variant), figure, compare, comparisons[compare])


def inference_comparison(preset: str = "small", repeats: int = 5, policy_path: str | None = None,
                         compare: str | None = None, **settings) -> dict:
    """``bench_inference`` with ``settings`` (its options and config overrides, e.g. ``dense_attention``,
    ``compile_inference``); with ``compare`` (a key of :data:`INFERENCE_COMPARISONS`) that setting on and off in
    alternation, and the ratio of their ``ms_per_control_step``."""

    def run(**kwargs) -> dict:
        return bench_inference(preset, repeats=repeats, policy_path=policy_path, **kwargs)

    return run_or_compare(run, "ms_per_control_step", settings, compare, INFERENCE_COMPARISONS)


def train_step_comparison(preset: str = "small", batch_size: int = 8, repeats: int = 5, compare: str | None = None,
                          **settings) -> dict:
    """``bench_train_step`` with ``settings`` (its options and config overrides, e.g. ``frame_cache``, ``use_amp``,
    ``dense_attention``); with ``compare`` (a key of :data:`TRAIN_STEP_COMPARISONS`) that setting on and off in
    alternation, and the ratio of their ``samples_per_s``."""

    def run(**kwargs) -> dict:
        return bench_train_step(preset, batch_size=batch_size, repeats=repeats, **kwargs)

    return run_or_compare(run, "samples_per_s", settings, compare, TRAIN_STEP_COMPARISONS)
