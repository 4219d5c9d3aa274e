"""A picture of what the encoder's nodes encode: an object's points, the M nodes and the decoded surface."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..geometry.sampling import resample_indices
from ..geometry.se3 import look_rotation, make_pose, transform_points
from ..model.occupancy import OccupancyNetwork
from ..model.point_ops import nearest_centroid
from ..objects.library import load_object
from ..objects.rendering import PointCloudRenderer
from .encoder_pretraining import classification_metrics
from .occupancy_data import OccupancyDataConfig, dense_surface, sample_queries

GRID_RESOLUTION = 48


def render_object(object_id: str, num_points: int = 2048, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """One object at the workspace centre, seen by the three cameras: ``points (P, 3)`` world and its pose."""
    T_world_object = make_pose([0.5, 0.0, 0.0], np.eye(3))
    T_world_ee = make_pose([0.3, 0.0, 0.6], look_rotation(np.array([0.0, 0.0, -1.0]), 0.0))
    with PointCloudRenderer() as renderer:
        renderer.set_objects([load_object(object_id)])
        cloud, _ = renderer.render([T_world_object], T_world_ee, True)
    if len(cloud) == 0:
        raise ValueError(f"object {object_id} is not visible to the cameras")
    return cloud[resample_indices(cloud, num_points, np.random.default_rng(seed))], T_world_object


@torch.no_grad()
def draw_occupancy(network: OccupancyNetwork, object_id: str, png: Path) -> dict:
    """Draw input points coloured by node, the nodes, and grid queries decoded as on-surface; return metrics."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    network.eval()
    points, T_world_object = render_object(object_id)
    points_t = torch.from_numpy(points)[None].float()
    node_positions, node_features = network.encoder(points_t)
    lower, upper = points.min(axis=0) - 0.02, points.max(axis=0) + 0.02
    axes = [np.linspace(lo, hi, GRID_RESOLUTION) for lo, hi in zip(lower, upper)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float32)
    grid_t = torch.from_numpy(grid)[None]
    on_surface = (network.decode(node_positions, node_features, grid_t)[0] > 0).numpy()
    decoded = grid[on_surface]
    decoded_nodes = nearest_centroid(torch.from_numpy(decoded)[None], node_positions)[0].numpy()
    point_nodes = nearest_centroid(points_t, node_positions)[0].numpy()

    data_config = OccupancyDataConfig()
    surface = transform_points(T_world_object, dense_surface(object_id, data_config.dense_samples))
    queries, labels = sample_queries(points.astype(np.float64), surface, np.random.default_rng(0), data_config)
    logits = network.decode(node_positions, node_features, torch.from_numpy(queries)[None])[0]
    metrics = classification_metrics(logits, torch.from_numpy(labels))

    nodes = node_positions[0].numpy()
    colours = plt.get_cmap("tab20")(np.arange(len(nodes)) % 20)
    figure = plt.figure(figsize=(12, 5.5))
    for panel, (title, cloud, groups) in enumerate(
        [
            ("input points by node, and the nodes", points, point_nodes),
            ("decoded on-surface grid queries", decoded, decoded_nodes),
        ]
    ):
        axis = figure.add_subplot(1, 2, panel + 1, projection="3d")
        axis.scatter(*cloud.T, s=1.5, c=colours[groups], depthshade=False)
        axis.scatter(*nodes.T, s=60, c=colours, edgecolors="black", marker="o", depthshade=False)
        axis.set_title(title)
        axis.set_box_aspect(np.ptp(np.concatenate([points, nodes]), axis=0))
        axis.set_axis_off()
    figure.suptitle(
        f"{object_id}: {len(nodes)} encoder nodes; balanced accuracy {metrics['balanced_accuracy']:.3f}, "
        f"IoU {metrics['iou']:.3f} on {len(queries)} queries"
    )
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(png, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return {"object": object_id, "png": str(png), "decoded_points": int(len(decoded)), **metrics}
