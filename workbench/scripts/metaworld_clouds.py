"""What an Instant Policy observation of LeRobot's MetaWorld env holds (docs/metaworld.md): per task, LeRobot's video
frame beside the segmented cloud (``--env.type=metaworld_pointcloud``: task objects and the goal marker, fused from
the MuJoCo depth + segmentation cameras) and the EE pose, at ``reset(seed)``.

    MUJOCO_GL=osmesa python workbench/scripts/metaworld_clouds.py --tasks pick-place-v3,drawer-open-v3,window-open-v3 \
        --out docs/metaworld_clouds.png
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "osmesa")

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from lerobot_instant_policy.sim.metaworld.env import MetaworldPointCloudEnv  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="pick-place-v3,drawer-open-v3,window-open-v3")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    tasks = args.tasks.split(",")
    figure = plt.figure(figsize=(7.0, 3.2 * len(tasks)))
    for row, task in enumerate(tasks):
        env = MetaworldPointCloudEnv(task)
        observation, _ = env.reset(seed=args.seed)
        frame = env.render()
        env.close()
        image_axes = figure.add_subplot(len(tasks), 2, 2 * row + 1)
        image_axes.imshow(frame)
        image_axes.set_title(f"{task}: LeRobot's video frame", fontsize=9)
        image_axes.axis("off")
        cloud_axes = figure.add_subplot(len(tasks), 2, 2 * row + 2, projection="3d")
        points = observation["pointcloud"]
        cloud_axes.scatter(points[:, 0], points[:, 1], points[:, 2], s=1, c=points[:, 2], cmap="viridis")
        ee = observation["agent_pos"][:3]
        cloud_axes.scatter([ee[0]], [ee[1]], [ee[2]], s=40, c="red", marker="x")
        cloud_axes.set_title(f"segmented cloud ({len(points)} points), EE: red x", fontsize=9)
        cloud_axes.set_xlabel("x (m)", fontsize=7)
        cloud_axes.set_ylabel("y (m)", fontsize=7)
        cloud_axes.set_zlabel("z (m)", fontsize=7)
        cloud_axes.tick_params(labelsize=6)
        cloud_axes.view_init(elev=30, azim=-120)
    figure.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
