"""Plot of the rung-1 studies in docs/journal.md (2026-11-23, "In-context learning: twice the samples in 30 minutes,
…"): held-out translation error over hold-still and the context gain, against training steps (one run's checkpoints)
and against the number of training tasks.

Each input is a ``lerobot-ip-action-error --json`` output; the figure and the figures' data go to OUT.png / OUT.json.

Usage: python workbench/scripts/rung1_study_plot.py OUT steps STEP=FILE ... tasks COUNT=FILE ...

``point`` reads one such output; ``task_count_plot.py`` uses it too.
"""

import json
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def point(path: str) -> dict:
    result = json.load(open(path))
    own, hold = result["settings"][0]["translation_mm"], result["hold"]["translation_mm"]
    return {"own_over_hold": round(own / hold, 3), "context_gain": result["context_gain"]["translation"]}


def main() -> None:
    out, arguments = sys.argv[1], sys.argv[2:]
    series, current = {"steps": {}, "tasks": {}}, None
    for argument in arguments:
        if argument in series:
            current = argument
            continue
        key, path = argument.split("=", 1)
        series[current][int(key)] = point(path)
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    labels = (("steps", "training steps (batch 8)"), ("tasks", "training tasks (2,200 steps)"))
    for axis, (name, label) in zip(axes, labels):
        xs = sorted(series[name])
        axis.plot(xs, [series[name][x]["own_over_hold"] for x in xs], "o-", label="translation error / hold-still")
        axis.plot(xs, [series[name][x]["context_gain"] for x in xs], "s-", label="context gain (swap / own)")
        axis.axhline(0.5, color="tab:blue", linestyle=":", label="issue target: error ≤ 0.5× hold")
        axis.axhline(2.0, color="tab:orange", linestyle=":", label="issue target: gain ≥ 2")
        axis.axhline(1.0, color="grey", linewidth=0.8)
        axis.set_xlabel(label)
        axis.set_ylim(0.3, 2.1)
        if name == "tasks":
            axis.set_xscale("log")
            axis.minorticks_off()
            axis.set_xticks(xs, [str(x) for x in xs])
    axes[0].set_title("rung 1, one 8,000-step run (26 min, CPU)")
    axes[1].set_title("rung 1, task count at equal steps")
    axes[0].legend(fontsize=7, loc="upper right")
    figure.tight_layout()
    figure.savefig(f"{out}.png", dpi=120)
    json.dump(series, open(f"{out}.json", "w"), indent=1)


if __name__ == "__main__":
    main()
