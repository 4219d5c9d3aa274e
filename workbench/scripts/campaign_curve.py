"""The training campaign's curve (issue 30): each checkpoint's held-out action error against holding still and its
context gain, on moved-object and on one-layout pseudo-tasks, from ``lerobot-ip-action-error --json``
outputs named ``<dir>/s<step>_{moved,shared}.json`` (step 0: the checkpoint the campaign started from).

    python workbench/scripts/campaign_curve.py outputs/eval --samples-per-step 8 --out docs/campaign_curve
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

SETS = {"moved": "objects moved between demonstrations", "shared": "one object layout"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--samples-per-step", type=int, default=8)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    points = []
    for path in sorted(args.folder.glob("s*_moved.json"), key=lambda p: int(re.findall(r"\d+", p.name)[0])):
        step = int(re.findall(r"\d+", path.name)[0])
        point = {"step": step, "samples": step * args.samples_per_step}
        for name in SETS:
            result = json.loads((args.folder / f"s{step}_{name}.json").read_text())
            own, hold = result["settings"][0]["translation_mm"], result["hold"]["translation_mm"]
            point[name] = {"translation_mm": own, "over_hold": round(own / hold, 3),
                           "context_gain": result["context_gain"]["translation"]}
        points.append(point)
    args.out.with_suffix(".json").write_text(json.dumps(points, indent=2) + "\n")
    figure, (error_axis, gain_axis) = plt.subplots(1, 2, figsize=(10, 3.6))
    samples = [point["samples"] / 1000 for point in points]
    for name, label in SETS.items():
        error_axis.plot(samples, [point[name]["over_hold"] for point in points], marker="o", label=label)
        gain_axis.plot(samples, [point[name]["context_gain"] for point in points], marker="o", label=label)
    error_axis.axhline(1.0, color="grey", lw=0.8, ls="--")
    gain_axis.axhline(1.0, color="grey", lw=0.8, ls="--")
    error_axis.set(xlabel="samples seen in the campaign (thousands)", ylabel="error / holding still",
                   title="held-out action error (lower is better)")
    gain_axis.set(xlabel="samples seen in the campaign (thousands)", ylabel="context gain",
                  title="context gain (higher is better)")
    error_axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(args.out.with_suffix(".png"), dpi=110)


if __name__ == "__main__":
    main()
