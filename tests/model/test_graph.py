"""Graph layout: edge types and counts, connectivity, caching, edge attributes and their invariance."""

import math

import pytest
import roma
import torch

from lerobot_instant_policy.geometry.gripper import GRIPPER_KEYPOINTS
from lerobot_instant_policy.model.encodings import sinusoidal_encoding
from lerobot_instant_policy.model.graph import (
    ACTION_TO_ACTION,
    CURRENT_TO_ACTION,
    DEMO_TIME,
    DEMO_TO_CURRENT,
    GRIPPER_TO_GRIPPER,
    SCENE_TO_GRIPPER,
    SCENE_TO_SCENE,
)
from lerobot_instant_policy.model.sparse_graphs import (
    action_graph,
    context_graph,
    keypoint_offset_attr,
    local_graph,
    transform_attr,
)

pytestmark = pytest.mark.usefixtures("single_torch_thread")


CPU = torch.device("cpu")
K = len(GRIPPER_KEYPOINTS)
KEYPOINTS = torch.tensor(GRIPPER_KEYPOINTS, dtype=torch.float64)


def _random_poses(count: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    T = torch.zeros(count, 4, 4, dtype=torch.float64)
    T[:, :3, :3] = roma.rotvec_to_rotmat(torch.randn(count, 3, generator=generator, dtype=torch.float64))
    T[:, :3, 3] = torch.randn(count, 3, generator=generator, dtype=torch.float64) * 0.3
    T[:, 3, 3] = 1.0
    return T


def test_gripper_keypoints_are_the_official_ones():
    assert GRIPPER_KEYPOINTS == (
        (0.0, 0.0, 0.0),
        (0.0, 0.0, -0.06),
        (0.0, 0.06, 0.0),
        (0.0, -0.06, 0.0),
        (0.0, 0.06, 0.06),
        (0.0, -0.06, 0.06),
    )


def test_local_graph_edges_stay_inside_each_local_graph():
    graph = local_graph(3, 5, K, CPU)
    assert graph[SCENE_TO_SCENE].edge_index.shape[1] == 3 * 5 * 4
    assert graph[SCENE_TO_GRIPPER].edge_index.shape[1] == 3 * 5 * K
    assert graph[GRIPPER_TO_GRIPPER].edge_index.shape[1] == 3 * K * (K - 1)
    src, dst = graph[SCENE_TO_SCENE].edge_index
    assert torch.equal(src // 5, dst // 5) and not (src == dst).any()
    src, dst = graph[SCENE_TO_GRIPPER].edge_index
    assert torch.equal(src // 5, dst // K)
    src, dst = graph[GRIPPER_TO_GRIPPER].edge_index
    assert torch.equal(src // K, dst // K) and not (src == dst).any()


def test_context_graph_links_waypoints_backwards_in_time_within_one_demo():
    batch, num_demos, length = 2, 3, 4
    graph = context_graph(batch, num_demos, length, K, CPU)
    src, dst = graph[DEMO_TIME].edge_index
    src_frame, dst_frame = src // K, dst // K
    assert torch.equal(src_frame, dst_frame + 1)
    assert torch.equal(src_frame // length, dst_frame // length)  # same demo of the same sample
    assert torch.equal(graph[DEMO_TIME].src_frame, src_frame) and torch.equal(graph[DEMO_TIME].dst_frame, dst_frame)
    assert torch.equal(graph[DEMO_TIME].dst_keypoint, dst % K)
    src, dst = graph[DEMO_TO_CURRENT].edge_index
    assert torch.equal(src // (num_demos * length * K), dst // K)  # demos of a sample feed only its current frame
    assert len(set(zip(src.tolist(), dst.tolist()))) == batch * num_demos * length * K * K


def test_action_graph_links_current_to_every_action_and_actions_pairwise():
    batch, horizon = 2, 5
    graph = action_graph(batch, horizon, K, CPU)
    src, dst = graph[CURRENT_TO_ACTION].edge_index
    assert torch.equal(src // K, dst // (K * horizon))
    assert src.shape[0] == batch * horizon * K * K
    src, dst = graph[ACTION_TO_ACTION].edge_index
    assert src.shape[0] == batch * horizon * (horizon - 1) * K * K
    assert torch.equal(src // (K * horizon), dst // (K * horizon))
    assert not (src // K == dst // K).any()


def _context_edges(num_demos: int, length: int) -> int:
    graph = context_graph(1, num_demos, length, K, CPU)
    return sum(graph[edge_type].edge_index.shape[1] for edge_type in graph.edge_types)


@pytest.mark.parametrize("vary", ["demos", "length"])
def test_edge_counts_grow_linearly_in_n_and_l(vary):
    sizes = [1, 2, 4, 8, 16]
    counts = [_context_edges(n, 10) if vary == "demos" else _context_edges(2, n) for n in sizes]
    slopes = [(b - a) / (m - n) for a, b, n, m in zip(counts, counts[1:], sizes, sizes[1:])]
    assert max(slopes) == pytest.approx(min(slopes))  # exactly linear: constant increment per demo / waypoint
    assert slopes[0] > 0


def test_connectivity_is_built_once_per_size():
    assert context_graph(2, 2, 10, K, CPU) is context_graph(2, 2, 10, K, CPU)
    assert action_graph(2, 8, K, CPU) is action_graph(2, 8, K, CPU)
    assert local_graph(4, 16, K, CPU) is local_graph(4, 16, K, CPU)
    assert context_graph(2, 3, 10, K, CPU) is not context_graph(2, 2, 10, K, CPU)


def test_transform_attr_encodes_translation_and_rotation_displacement():
    graph = action_graph(1, 2, K, CPU)
    store = graph[CURRENT_TO_ACTION]
    current = torch.eye(4, dtype=torch.float64)[None]
    actions = _random_poses(2, seed=1)
    attr = transform_attr(current, actions, store, KEYPOINTS, num_frequencies=10)
    assert attr.shape == (2 * K * K, 2 * 63)
    # The raw vectors are the last 3 entries of each encoding.
    for edge in range(attr.shape[0]):
        T = actions[store.dst_frame[edge]]
        keypoint = KEYPOINTS[store.dst_keypoint[edge]]
        torch.testing.assert_close(attr[edge, 60:63], T[:3, 3])
        torch.testing.assert_close(attr[edge, 123:126], T[:3, :3] @ keypoint - keypoint)
    torch.testing.assert_close(attr[0, :63], sinusoidal_encoding(actions[0, :3, 3], 10))


def test_transform_attr_between_frames_does_not_depend_on_the_world():
    graph = context_graph(1, 2, 5, K, CPU)
    frames = _random_poses(10, seed=2)
    moved = _random_poses(1, seed=3) @ frames
    attr = transform_attr(frames, frames, graph[DEMO_TIME], KEYPOINTS, 10)
    torch.testing.assert_close(transform_attr(moved, moved, graph[DEMO_TIME], KEYPOINTS, 10), attr)
    # And it does depend on the relative motion.
    frames[3, :3, 3] += 0.05
    assert not torch.allclose(transform_attr(frames, frames, graph[DEMO_TIME], KEYPOINTS, 10), attr)


def test_identity_transform_gives_zero_motion_attribute():
    graph = action_graph(1, 2, K, CPU)
    identity = torch.eye(4, dtype=torch.float64).expand(2, 4, 4)
    attr = transform_attr(identity[:1], identity, graph[CURRENT_TO_ACTION], KEYPOINTS, 4)
    zero = sinusoidal_encoding(torch.zeros(3, dtype=torch.float64), 4)
    torch.testing.assert_close(attr, torch.cat([zero, zero]).expand_as(attr))


def test_demo_to_current_attribute_is_the_keypoint_offset():
    graph = context_graph(1, 1, 1, K, CPU)
    store = graph[DEMO_TO_CURRENT]
    attr = keypoint_offset_attr(store, KEYPOINTS, 10)
    src, dst = store.edge_index
    torch.testing.assert_close(attr[:, 60:63], KEYPOINTS[dst % K] - KEYPOINTS[src % K])
    assert math.isclose(float(attr[:, 60:63].norm(dim=-1).max()), math.hypot(0.12, 0.06))
