"""Every fast path of issue 12 gives its reference's outputs: torch-geometric layers, roma, or the plain formula."""

from __future__ import annotations

import math

import pytest
import roma
import torch
from torch_geometric.nn import TransformerConv

from lerobot_instant_policy.geometry.rigid_torch import fit_rigid
from lerobot_instant_policy.model import graph_transformer
from lerobot_instant_policy.model.dense_attention import dense_transformer_conv
from lerobot_instant_policy.model.dense_graphs import dense_local_masks, dense_position_attr
from lerobot_instant_policy.model.encodings import sinusoidal_encoding
from lerobot_instant_policy.model.graph import (
    GRIPPER,
    GRIPPER_TO_GRIPPER,
    SCENE,
    SCENE_TO_GRIPPER,
    SCENE_TO_SCENE,
)
from lerobot_instant_policy.model.graph_transformer import HeteroGraphTransformer, fixed_weights
from lerobot_instant_policy.model.point_ops import group_max

pytestmark = pytest.mark.usefixtures("single_torch_thread")

EDGE_DIMS = {SCENE_TO_SCENE: 9, SCENE_TO_GRIPPER: 9, GRIPPER_TO_GRIPPER: 9}


def test_shared_source_attributes_match_transformer_conv_on_every_edge():
    """Attributes shared by r consecutive sources (ψ's keypoints of a frame) give the conv on the expanded edges."""
    generator = torch.Generator().manual_seed(0)
    graphs, frames, shared, destinations, width, edge_dim = 3, 4, 5, 6, 32, 7
    sources = frames * shared
    conv = TransformerConv(width, 8, heads=4, edge_dim=edge_dim)
    x_src = torch.randn(graphs, sources, width, generator=generator, requires_grad=True)
    x_dst = torch.randn(graphs, destinations, width, generator=generator, requires_grad=True)
    attr = torch.randn(graphs, frames, destinations, edge_dim, generator=generator, requires_grad=True)
    dense = dense_transformer_conv(conv, x_src, x_dst, attr)

    g, s, d = torch.nonzero(torch.ones(graphs, sources, destinations), as_tuple=True)
    edge_index = torch.stack([g * sources + s, g * destinations + d])
    sparse = conv((x_src.reshape(-1, width), x_dst.reshape(-1, width)), edge_index, attr[g, s // shared, d])
    torch.testing.assert_close(dense.reshape(-1, width), sparse, atol=1e-5, rtol=1e-5)
    for dense_grad, sparse_grad in zip(*(torch.autograd.grad(out.square().sum(), [x_src, x_dst, attr])
                                         for out in (dense.reshape(-1, width), sparse)), strict=True):
        torch.testing.assert_close(dense_grad, sparse_grad, atol=1e-4, rtol=1e-4)


def _local_inputs(graphs: int, generator: torch.Generator, expanded: bool = False):
    scene = 0.1 * torch.randn(graphs, 5, 3, generator=generator)
    gripper = 0.1 * torch.randn(graphs, 3, 3, generator=generator)
    scene_features = torch.randn(1 if expanded else graphs, 5, 16, generator=generator)
    x = {SCENE: scene_features.expand(graphs, -1, -1), GRIPPER: torch.randn(graphs, 3, 16, generator=generator)}
    attr = {
        SCENE_TO_SCENE: dense_position_attr(scene, scene, 1),
        SCENE_TO_GRIPPER: dense_position_attr(scene, gripper, 1),
        GRIPPER_TO_GRIPPER: dense_position_attr(gripper, gripper, 1),
    }
    return x, attr, dense_local_masks(5, 3, torch.device("cpu"))


def _reference_forward_dense(network: HeteroGraphTransformer, x_dict, edge_attr_dict, mask_dict):
    """The stack with every conv run on its own by :func:`dense_transformer_conv` (tested against PyG)."""
    for layer in network.layers:
        attended = {}
        for edge_type, conv in layer.attention.convs.items():
            source, _, destination = edge_type
            update = dense_transformer_conv(conv, x_dict[source], x_dict[destination], edge_attr_dict[edge_type],
                                            mask_dict[edge_type])
            attended[destination] = attended[destination] + update if destination in attended else update
        x_dict = layer._update(x_dict, attended)
    return {node: x_dict[node] for node in network.output_node_types}


@pytest.mark.parametrize("expanded", [False, True])
def test_stacked_projections_give_every_conv_its_own(expanded):
    """One matrix product per node type (and one per row for a node type expanded along the graphs) gives the
    outputs and gradients of the convs' own projections."""
    generator = torch.Generator().manual_seed(1)
    torch.manual_seed(0)
    network = HeteroGraphTransformer(EDGE_DIMS, [GRIPPER], num_layers=2, hidden_dim=16, num_heads=2, mlp_ratio=2)
    x, attr, masks = _local_inputs(4, generator, expanded)
    results = []
    for forward in (network.forward_dense, lambda *args: _reference_forward_dense(network, *args)):
        network.zero_grad()
        out = forward(x, attr, masks)[GRIPPER]
        out.square().sum().backward()
        results.append((out.detach(), [p.grad.clone() for p in network.parameters() if p.grad is not None]))
    (fast, fast_grads), (reference, reference_grads) = results
    torch.testing.assert_close(fast, reference, atol=1e-5, rtol=1e-5)
    assert len(fast_grads) == len(reference_grads) > 10
    for fast_grad, reference_grad in zip(fast_grads, reference_grads, strict=True):
        torch.testing.assert_close(fast_grad, reference_grad, atol=1e-4, rtol=1e-4)


def test_weights_stacked_once_per_fixed_weights_block_give_the_same_outputs():
    """Inside :func:`fixed_weights` the stacked projections are reused across calls; after the block a weight change
    is seen again."""
    generator = torch.Generator().manual_seed(6)
    network = HeteroGraphTransformer(EDGE_DIMS, [GRIPPER], num_layers=2, hidden_dim=16, num_heads=2, mlp_ratio=2)
    x, attr, masks = _local_inputs(4, generator)
    with torch.no_grad():
        reference = network.forward_dense(x, attr, masks)[GRIPPER]
        with fixed_weights(network):
            first, second = (network.forward_dense(x, attr, masks)[GRIPPER] for _ in range(2))
        torch.testing.assert_close(first, reference, atol=0, rtol=0)
        torch.testing.assert_close(second, reference, atol=0, rtol=0)
        conv = network.layers[0].attention.convs[SCENE_TO_GRIPPER]
        conv.lin_query.weight.add_(0.5)
        changed = network.forward_dense(x, attr, masks)[GRIPPER]
    assert not torch.allclose(changed, reference)


def test_attributes_cast_once_under_autocast_give_the_same_outputs(monkeypatch):
    """Autocast casts the attributes to bfloat16 at every matrix product; casting them once first is the same."""
    generator = torch.Generator().manual_seed(2)
    network = HeteroGraphTransformer(EDGE_DIMS, [GRIPPER], num_layers=2, hidden_dim=16, num_heads=2, mlp_ratio=2)
    x, attr, masks = _local_inputs(4, generator)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        cast_once = network.forward_dense(x, attr, masks)[GRIPPER]
        monkeypatch.setattr(graph_transformer, "_dense_attr_layout", lambda value: value)
        cast_per_product = network.forward_dense(x, attr, masks)[GRIPPER]
    # The same bfloat16 operands; only the memory layout a matrix product reads them in may move the last bit.
    torch.testing.assert_close(cast_once, cast_per_product, atol=2e-2, rtol=2e-2)


def test_dense_position_attr_is_the_encoded_offset_of_every_pair():
    generator = torch.Generator().manual_seed(3)
    src, dst = torch.randn(2, 4, 3, generator=generator), torch.randn(2, 5, 3, generator=generator)
    attr = dense_position_attr(src, dst, 3)
    assert attr.shape == (2, 4, 5, 21)
    assert attr.transpose(1, 2).is_contiguous()  # destination-major in memory
    assert torch.equal(attr, sinusoidal_encoding(dst[:, None, :, :] - src[:, :, None, :], 3))


def test_sinusoidal_encoding_is_the_formula_and_its_cached_frequencies_serve_autograd():
    vectors = torch.randn(7, 3, dtype=torch.float64)
    with torch.inference_mode():  # caches the frequencies first in inference mode
        sinusoidal_encoding(vectors, 4)
    angles = torch.cat([vectors * (2.0**k * math.pi) for k in range(4)], dim=-1)
    expected = torch.cat([angles.sin(), angles.cos(), vectors], dim=-1)
    leaf = vectors.clone().requires_grad_(True)
    encoded = sinusoidal_encoding(leaf, 4)
    torch.testing.assert_close(encoded, expected, atol=0, rtol=1e-15)
    encoded.sum().backward()
    assert leaf.grad is not None


def test_group_max_matches_scatter_reduce_in_values_and_gradients():
    generator = torch.Generator().manual_seed(4)
    values = torch.randn(3, 40, 6, generator=generator, requires_grad=True)
    groups = torch.randint(0, 12, (3, 40), generator=generator)  # some groups stay empty
    index = groups[..., None].expand(-1, -1, 6)
    reference = values.new_zeros(3, 12, 6).scatter_reduce(1, index, values, reduce="amax", include_self=False)
    pooled = group_max(values, groups, 12)
    assert torch.equal(pooled, reference)
    weights = torch.randn(3, 12, 6, generator=generator)
    fast_grad, reference_grad = (torch.autograd.grad((out * weights).sum(), values)[0] for out in (pooled, reference))
    assert torch.equal(fast_grad, reference_grad)


@pytest.mark.parametrize("angle_scale", [0.05, 3.0])
def test_fit_rigid_is_roma_rigid_points_registration(angle_scale):
    generator = torch.Generator().manual_seed(5)
    source = 0.1 * torch.randn(4, 8, 6, 3, generator=generator)
    R = roma.rotvec_to_rotmat(angle_scale * torch.randn(4, 8, 3, generator=generator).clamp(-1, 1))
    t = 0.05 * torch.randn(4, 8, 3, generator=generator)
    target = source @ R.transpose(-1, -2) + t[..., None, :] + 1e-3 * torch.randn(source.shape, generator=generator)
    R_fit, t_fit = fit_rigid(source, target)
    R_roma, t_roma = roma.rigid_points_registration(source, target)
    torch.testing.assert_close(R_fit, R_roma, atol=1e-5, rtol=0)
    torch.testing.assert_close(t_fit, t_roma, atol=1e-6, rtol=0)
    assert torch.allclose(torch.det(R_fit), torch.ones(4, 8))


def test_fused_adamw_preset_matches_the_loop_implementation():
    """The policy's optimizer preset fuses AdamW on the CPU, and its updates equal PyTorch's loop AdamW's."""
    from lerobot_instant_policy.configuration_instant_policy import InstantPolicyConfig
    from lerobot_instant_policy.modeling_instant_policy import InstantPolicyPolicy

    config = InstantPolicyConfig(device="cpu", optimizer_lr=1e-3)
    preset = config.get_optimizer_preset()
    assert preset.type == "instant_policy_adamw" and preset.grad_clip_norm == config.optimizer_grad_clip_norm
    fused_policy = InstantPolicyPolicy(config)
    loop_policy = InstantPolicyPolicy(config)
    loop_policy.load_state_dict(fused_policy.state_dict())
    fused = preset.build(fused_policy.get_optim_params())
    loop = type(preset)(**{**preset.__dict__, "fused": False}).build(loop_policy.get_optim_params())
    assert fused.defaults["fused"] is True and not loop.defaults["fused"]
    initial = [p.detach().clone() for p in fused_policy.get_optim_params()]
    generator = torch.Generator().manual_seed(0)
    for _ in range(3):
        for a, b in zip(fused_policy.get_optim_params(), loop_policy.get_optim_params(), strict=True):
            a.grad = torch.randn(a.shape, generator=generator)
            b.grad = a.grad.clone()
        fused.step()
        loop.step()
    for (name, a), b in zip(fused_policy.named_parameters(), loop_policy.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6, msg=name)
    assert all(not torch.equal(p, p0) for p, p0 in zip(fused_policy.get_optim_params(), initial, strict=True))


def test_a_fresh_optimizer_rebuilds_its_moments_before_it_moves_the_weights():
    """With moment_rebuild_steps 3 a fresh optimizer keeps the weights for 3 steps while its moments fill, then its
    fourth step equals AdamW's fourth on the same gradients where the moments are the same; a state that has taken
    3 steps already (a full save resumed) moves at once. The rates the scheduler set survive the rebuild steps."""
    from lerobot_instant_policy.training.optimizer import InstantPolicyAdamWConfig

    generator = torch.Generator().manual_seed(0)
    weights = torch.randn(5, 4, generator=generator)
    gradients = [torch.randn(5, 4, generator=generator) for _ in range(4)]
    config = InstantPolicyAdamWConfig(lr=1e-2, weight_decay=0.1, moment_rebuild_steps=3)
    rebuilt = torch.nn.Parameter(weights.clone())
    optimizer = config.build([rebuilt])
    plain = torch.nn.Parameter(weights.clone())
    reference = InstantPolicyAdamWConfig(lr=1e-2, weight_decay=0.1).build([plain])
    for index, gradient in enumerate(gradients):
        for parameter, opt in ((rebuilt, optimizer), (plain, reference)):
            parameter.grad = gradient.clone()
            if index < 3 and opt is reference:
                for group in opt.param_groups:
                    group["lr"] = 0.0
            opt.step()
            if opt is reference:
                for group in opt.param_groups:
                    group["lr"] = 1e-2
        if index < 3:
            assert torch.equal(rebuilt, weights) and optimizer.param_groups[0]["lr"] == 1e-2
    assert not torch.equal(rebuilt, weights)
    torch.testing.assert_close(rebuilt, plain)
    assert optimizer.steps_taken() == 4
    resumed = torch.nn.Parameter(weights.clone())
    again = config.build([resumed])
    again.load_state_dict(optimizer.state_dict())
    resumed.grad = gradients[0].clone()
    again.step()
    assert not torch.equal(resumed, weights)


def test_moment_rebuild_steps_must_be_non_negative():
    from lerobot_instant_policy.training.optimizer import InstantPolicyAdamWConfig

    with pytest.raises(ValueError, match="moment_rebuild_steps"):
        InstantPolicyAdamWConfig(moment_rebuild_steps=-1)
