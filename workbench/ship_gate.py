"""The ship gate: whether a candidate checkpoint replaces the shipped one, decided on the test split of every
benchmark at once.

Each benchmark alone (the suite's 12 tasks, MetaWorld MT10's 10) holds too few tasks for a cluster interval to
resolve a difference of 10 points; pooled, their 22 tasks can. The candidate and the shipped checkpoint are two
columns of each benchmark's joined table (``lerobot-ip-eval-table``'s ``OUT.manifest.json``, as
``make results-candidate`` writes it), evaluated on the same episodes. The gate pairs them per benchmark
(``evaluation.paired``, the task the resampled cluster) and over the union of all benchmarks' tasks, a task named
with its benchmark so that two benchmarks' tasks of one name stay two clusters: for task k of any benchmark,
``d_k`` = (the candidate's successes − the shipped checkpoint's) over its ``n_k`` episodes and

    Δ_pooled = Σ_k d_k / Σ_k n_k,

every task weighted by its episodes (30 each on both test splits), its 95% interval the cluster bootstrap over the
pooled tasks. The candidate **ships** when Δ_pooled's interval lies wholly above zero and no benchmark's own
interval lies wholly below zero (a candidate better on the whole but resolved worse on one benchmark does not ship).

``python -m workbench.cli.ship_gate CANDIDATE SHIPPED SUITE.manifest.json MT10.manifest.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lerobot_instant_policy.evaluation.manifest import CellOutcome, ManifestError, cells_of, read_manifest_file
from lerobot_instant_policy.evaluation.paired import RESAMPLES, PairedDifference, paired_difference


@dataclass(frozen=True)
class GateDecision:
    """The candidate's paired difference from the shipped checkpoint on each benchmark (by its manifest's stem) and
    pooled over all their tasks, and whether it ships (module docstring)."""

    candidate: str
    shipped: str
    per_benchmark: dict[str, PairedDifference]
    pooled: PairedDifference

    @property
    def ships(self) -> bool:
        return self.pooled.low > 0 and all(not difference.high < 0 for difference in self.per_benchmark.values())

    @property
    def reason(self) -> str:
        worse = [name for name, difference in self.per_benchmark.items() if difference.high < 0]
        if worse:
            return f"resolved worse than {self.shipped} on {', '.join(worse)}"
        if self.pooled.low > 0:
            return f"resolved better than {self.shipped} pooled over {self.pooled.clusters} tasks, worse on none"
        if self.pooled.high < 0:
            return f"resolved worse than {self.shipped} pooled over {self.pooled.clusters} tasks"
        return f"no difference from {self.shipped} resolved pooled over {self.pooled.clusters} tasks"

    def as_json(self) -> dict:
        return {"candidate": self.candidate, "shipped": self.shipped, "ships": self.ships, "reason": self.reason,
                "pooled": self.pooled.as_json(),
                "per_benchmark": {name: difference.as_json() for name, difference in self.per_benchmark.items()}}


def _columns(path: Path, candidate: str, shipped: str) -> tuple[dict[tuple[str, int], CellOutcome], ...]:
    return tuple(cells_of(read_manifest_file(path, column)[column]) for column in (candidate, shipped))


def ship_gate(candidate: str, shipped: str, tables: list[Path], resamples: int = RESAMPLES,
              seed: int = 0) -> GateDecision:
    """The gate's decision for column ``candidate`` against column ``shipped`` of each joined table in ``tables``
    (at least two benchmarks, each named by its file's stem; ``ManifestError`` when a table lacks a column, when the
    two columns' cells or seeds differ, or when two tables share a stem)."""
    if len(tables) < 2:
        raise ValueError(f"the gate pools at least two benchmarks' tables, got {len(tables)}")
    per_benchmark: dict[str, PairedDifference] = {}
    pooled_candidate: dict[tuple[str, int], CellOutcome] = {}
    pooled_shipped: dict[tuple[str, int], CellOutcome] = {}
    for path in tables:
        name = path.name.removesuffix(".manifest.json")
        if name in per_benchmark:
            raise ManifestError(f"two tables are named {name!r}; the gate names each benchmark by its file")
        cells_candidate, cells_shipped = _columns(path, candidate, shipped)
        per_benchmark[name] = paired_difference(candidate, cells_candidate, shipped, cells_shipped, resamples, seed)
        for cells, pooled in ((cells_candidate, pooled_candidate), (cells_shipped, pooled_shipped)):
            pooled.update({(f"{name}/{task}", demo_set): cell for (task, demo_set), cell in cells.items()})
    pooled = paired_difference(candidate, pooled_candidate, shipped, pooled_shipped, resamples, seed)
    return GateDecision(candidate, shipped, per_benchmark, pooled)
