"""The dense fast path of σ, φ and ψ gives the outputs and gradients of the torch-geometric reference layers."""

from __future__ import annotations

import pytest
import roma
import torch
from torch_geometric.nn import TransformerConv

from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
from lerobot_instant_policy.model.dense_attention import dense_transformer_conv
from lerobot_instant_policy.model.dense_graphs import DenseGraphs, dense_transform_attr
from lerobot_instant_policy.model.graph import ACTION_TO_ACTION
from lerobot_instant_policy.model.instant_policy_network import DemoTensors, InstantPolicyNetwork
from lerobot_instant_policy.model.sparse_graphs import SparseGraphs, action_graph, transform_attr

pytestmark = pytest.mark.usefixtures("single_torch_thread")


def _random_poses(*shape: int, generator: torch.Generator) -> torch.Tensor:
    T = torch.eye(4).expand(*shape, 4, 4).clone()
    T[..., :3, :3] = roma.random_rotmat(shape, generator=generator)
    T[..., :3, 3] = 0.1 * torch.randn(*shape, 3, generator=generator)
    return T


@pytest.mark.parametrize("masked", [False, True])
def test_dense_transformer_conv_matches_transformer_conv(masked):
    generator = torch.Generator().manual_seed(0)
    graphs, sources, destinations, width, edge_dim = 5, 7, 7, 32, 9
    conv = TransformerConv(width, 8, heads=4, edge_dim=edge_dim)
    x_src = torch.randn(graphs, sources, width, generator=generator, requires_grad=True)
    x_dst = torch.randn(graphs, destinations, width, generator=generator, requires_grad=True)
    attr = torch.randn(graphs, sources, destinations, edge_dim, generator=generator, requires_grad=True)
    mask = ~torch.eye(sources, dtype=torch.bool) if masked else torch.ones(sources, destinations, dtype=torch.bool)
    dense = dense_transformer_conv(conv, x_src, x_dst, attr, mask if masked else None)

    g, s, d = torch.nonzero(mask.expand(graphs, -1, -1), as_tuple=True)
    edge_index = torch.stack([g * sources + s, g * destinations + d])
    sparse = conv((x_src.reshape(-1, width), x_dst.reshape(-1, width)), edge_index, attr[g, s, d])
    torch.testing.assert_close(dense.reshape(-1, 32), sparse, atol=1e-5, rtol=1e-5)

    gradients = []
    for out in (dense.reshape(-1, 32), sparse):
        grads = torch.autograd.grad(out.square().sum(), [x_src, x_dst, attr, conv.lin_edge.weight, conv.lin_key.weight])
        gradients.append(grads)
    for dense_grad, sparse_grad in zip(*gradients, strict=True):
        torch.testing.assert_close(dense_grad, sparse_grad, atol=1e-4, rtol=1e-4)


def test_dense_transformer_conv_refuses_a_conv_it_does_not_compute():
    conv = TransformerConv(16, 4, heads=2)  # no edge attributes
    with pytest.raises(ValueError, match="needs a TransformerConv with edge_dim"):
        dense_transformer_conv(conv, torch.zeros(1, 2, 16), torch.zeros(1, 2, 16), torch.zeros(1, 2, 2, 3))


def test_dense_transform_attr_is_transform_attr_on_every_edge():
    generator = torch.Generator().manual_seed(1)
    batch, horizon, keypoints = 2, 3, torch.randn(4, 3, generator=generator) * 0.05
    frames = _random_poses(batch, horizon, generator=generator)
    dense = dense_transform_attr(frames, frames, keypoints, num_frequencies=4)
    graph = action_graph(batch, horizon, len(keypoints), torch.device("cpu"))
    store = graph[ACTION_TO_ACTION]
    sparse = transform_attr(frames.reshape(-1, 4, 4), frames.reshape(-1, 4, 4), store, keypoints, 4)
    nodes = horizon * len(keypoints)
    src, dst = store.edge_index
    src_frame = (src % nodes) // len(keypoints)  # one attribute per source frame, shared by its keypoints
    torch.testing.assert_close(dense[src // nodes, src_frame, dst % nodes], sparse)


def test_network_dense_and_reference_paths_agree():
    """The same weights give the same flows and gripper logits, and the same gradients, on either path."""
    generator = torch.Generator().manual_seed(2)
    torch.manual_seed(0)
    config = InstantPolicyConfig(reencode_action_clouds=False, pretrained_encoder=False, device="cpu")
    network = InstantPolicyNetwork(config)
    batch, num_demos, length = 2, 2, 3
    demo_T = _random_poses(batch, num_demos, length, generator=generator)
    demo_points = 0.1 * torch.randn(batch, num_demos, length, 2048, 3, generator=generator) + demo_T[..., None, :3, 3]
    T_world_ee = _random_poses(batch, generator=generator)
    points = 0.1 * torch.randn(batch, 2048, 3, generator=generator) + T_world_ee[:, None, :3, 3]
    T_ee_actions = _random_poses(batch, 8, generator=generator)
    T_ee_actions[..., :3, 3] *= 0.2
    results = []
    for dense in (True, False):
        graphs = DenseGraphs if dense else SparseGraphs
        network.graphs = graphs(network.local_network, network.context_network, network.action_network,
                                config.num_frequencies)
        network.zero_grad()
        demos = DemoTensors(demo_T, torch.ones(batch, num_demos, length),
                            *network.encode_observation(demo_points, demo_T))
        context = network.encode_context(demos, points, T_world_ee, torch.ones(batch))
        out = network.denoise(context, T_ee_actions, torch.full((batch, 8), -1.0), torch.tensor([5, 70]))
        out.square().sum().backward()
        grads = [p.grad.clone() for p in network.parameters() if p.grad is not None]
        results.append((out.detach(), grads))
    (dense_out, dense_grads), (reference_out, reference_grads) = results
    torch.testing.assert_close(dense_out, reference_out, atol=1e-5, rtol=1e-5)
    assert len(dense_grads) == len(reference_grads) > 10
    for dense_grad, reference_grad in zip(dense_grads, reference_grads, strict=True):
        torch.testing.assert_close(dense_grad, reference_grad, atol=1e-4, rtol=1e-3)


@pytest.mark.parametrize("num_demos, demo_length", [(1, 2), (3, 4), (2, 3)])
def test_dense_context_network_is_the_reference_on_demo_and_current_nodes(num_demos, demo_length):
    """φ alone: the same current gripper nodes and the same gradients (demo and current nodes, φ's weights) on the
    dense layout as on torch-geometric's layers, including the last waypoint, which receives no time edge."""
    generator = torch.Generator().manual_seed(3)
    torch.manual_seed(0)
    config = InstantPolicyConfig(pretrained_encoder=False, device="cpu")
    network = InstantPolicyNetwork(config)
    batch, hidden = 2, (network.num_keypoints, config.hidden_dim)
    T_world_ee = _random_poses(batch, num_demos, demo_length, generator=generator)
    demo = torch.randn(batch, num_demos, demo_length, *hidden, generator=generator, requires_grad=True)
    current = torch.randn(batch, *hidden, generator=generator, requires_grad=True)
    results = []
    for dense in (True, False):
        graphs = DenseGraphs if dense else SparseGraphs
        network.graphs = graphs(network.local_network, network.context_network, network.action_network,
                                config.num_frequencies)
        out = network._context_features(T_world_ee, demo, current)
        grads = torch.autograd.grad(out.square().sum(), [demo, current, *network.context_network.parameters()],
                                    allow_unused=True)
        results.append((out.detach(), grads))
    (dense_out, dense_grads), (reference_out, reference_grads) = results
    torch.testing.assert_close(dense_out, reference_out, atol=1e-5, rtol=1e-5)
    assert sum(grad is not None for grad in dense_grads) > 10
    for dense_grad, reference_grad in zip(dense_grads, reference_grads, strict=True):
        assert (dense_grad is None) == (reference_grad is None)
        if dense_grad is not None:
            torch.testing.assert_close(dense_grad, reference_grad, atol=1e-4, rtol=1e-3)
