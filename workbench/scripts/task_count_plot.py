"""Plot of the rung-4 task-count study in docs/journal.md (2026-11-25, "In-context learning: rungs 3 and 4 in one
layout, …"): translation error over hold-still and the context gain against the number of distinct training tasks,
on held-out tasks and on the first training tasks.

Each run gives two ``lerobot-ip-action-error --json`` outputs: on the held-out set and on the training set's first
tasks (which every run trained on). The figure and its data go to OUT.png / OUT.json.

Usage: python workbench/scripts/task_count_plot.py OUT COUNT=HELD_OUT.json:TRAINING.json ...
"""

import json
import sys

# the same reading of one action-error output, and pyplot on the Agg backend that the script selects
from rung1_study_plot import plt, point

out, arguments = sys.argv[1], sys.argv[2:]
runs = {}
for argument in arguments:
    count, paths = argument.split("=", 1)
    held_out, training = paths.split(":", 1)
    runs[int(count)] = {"held_out": point(held_out), "training_tasks": point(training)}
counts = sorted(runs)
figure, axes = plt.subplots(1, 2, figsize=(10, 3.8))
panels = (("own_over_hold", "translation error / hold-still", 0.5, "issue target: ≤ 0.5×"),
          ("context_gain", "context gain (swap / own)", 2.0, "issue target: ≥ 2"))
for axis, (key, label, target, target_label) in zip(axes, panels):
    axis.plot(counts, [runs[c]["held_out"][key] for c in counts], "o-", label="held-out tasks, held-out objects")
    axis.plot(counts, [runs[c]["training_tasks"][key] for c in counts], "s--", label="24 of its training tasks")
    axis.axhline(target, color="grey", linestyle=":", label=target_label)
    axis.axhline(1.0, color="grey", linewidth=0.8)
    axis.set_xscale("log")
    axis.minorticks_off()
    axis.set_xticks(counts, [str(c) for c in counts])
    axis.set_xlabel("distinct training tasks (8,000 steps of batch 8 each)")
    axis.set_ylabel(label)
axes[0].set_title("rung 4 (full generator), error")
axes[1].set_title("rung 4 (full generator), reading the demonstrations")
axes[0].legend(fontsize=7)
figure.tight_layout()
figure.savefig(f"{out}.png", dpi=120)
json.dump(runs, open(f"{out}.json", "w"), indent=1)
