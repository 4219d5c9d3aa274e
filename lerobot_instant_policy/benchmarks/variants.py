"""One setting of a benchmark on and off in alternation, in one run: the medians of a figure and their ratio.

Timings drift with the machine's load and temperature; alternating the two variants within one process and taking
medians over rounds makes their ratio the figure to trust, rather than two numbers from two separate runs.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable


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
