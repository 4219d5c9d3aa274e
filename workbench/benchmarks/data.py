"""Speed of a training row's data: LeRobot's delta-timestamp action chunks against the policy's action table.

Both paths read the same rows of a dataset through ``LeRobotDataset.__getitem__`` (what ``lerobot-train``'s data
loader workers run). ``delta_timestamps`` adds LeRobot's query of the ``T`` following actions to each row;
``action_table`` reads the row alone and looks its chunk up in
:class:`~lerobot_instant_policy.data.action_chunks.ActionChunks`, as the policy does in training.
"""

from __future__ import annotations

import statistics
import time

import numpy as np


def bench_data(repo_id: str, root: str, rows: int = 200, horizon: int = 8, repeats: int = 3, seed: int = 0) -> dict:
    """Median milliseconds per row of both paths over ``rows`` random rows, in alternation ``repeats`` times."""
    from lerobot.datasets import LeRobotDataset

    from lerobot_instant_policy.contract import ACTION_KEY
    from lerobot_instant_policy.data.action_chunks import ActionChunks

    plain = LeRobotDataset(repo_id, root=root)
    chunked = LeRobotDataset(repo_id, root=root,
                             delta_timestamps={ACTION_KEY: [step / plain.fps for step in range(horizon)]})
    start = time.perf_counter()
    table = ActionChunks.from_dataset(repo_id, root)
    table_s = time.perf_counter() - start
    indices = np.random.default_rng(seed).integers(0, len(plain), rows)

    def delta_timestamps() -> None:
        for index in indices:
            chunked[int(index)]

    def action_table() -> None:
        for index in indices:
            item = plain[int(index)]
            table.chunks(item["index"].numpy()[None], horizon)

    times: dict[str, list[float]] = {"delta_timestamps": [], "action_table": []}
    for _ in range(repeats):
        for name, read in (("delta_timestamps", delta_timestamps), ("action_table", action_table)):
            start = time.perf_counter()
            read()
            times[name].append(1000 * (time.perf_counter() - start) / rows)
    old, new = (statistics.median(times[name]) for name in ("delta_timestamps", "action_table"))
    return {
        "benchmark": "data", "root": str(root), "frames": len(plain), "rows": rows, "T": horizon, "repeats": repeats,
        "ms_per_row_delta_timestamps": round(old, 2), "ms_per_row_action_table": round(new, 2),
        "speedup": round(old / new, 2), "table_build_s": round(table_s, 2),
        "runs_delta_timestamps": [round(value, 2) for value in times["delta_timestamps"]],
        "runs_action_table": [round(value, 2) for value in times["action_table"]],
    }
