"""A PyG :class:`TransformerConv` evaluated densely on many small graphs whose edges join every source node to every
destination node (the local graphs of σ): the same weights and the same maths, without scatter operations.

For ``G`` graphs, each with ``S`` source and ``D`` destination nodes, and the edge ``j → i`` present where
``mask[j, i]``, the layer computes per head ``h`` (width ``C``), with the conv's own linear maps (paper eq. 3)::

    q_i = W_q x_i,   k_j = W_k x_j,   v_j = W_v x_j,   e_ji = W_e a_ji
    α_ji = softmax_j( q_i · (k_j + e_ji) / √C )          (over the sources j of i)
    x'_i = W_skip x_i + ‖_h Σ_j α_ji (v_j + e_ji)

which is exactly ``TransformerConv(heads=H, concat=True, root_weight=True, beta=False, dropout=0)`` on the same
graph (tested against it). Dense layout: ``x_src (G, S, F)``, ``x_dst (G, D, F)``, ``edge_attr (G, S, D, E)``.

``W_e`` is linear without bias, so the per-edge projections ``e_ji`` (``G·S·D·H·C`` numbers) are never formed:
``q_i · e_ji = (W_eᵀ q_i) · a_ji`` and ``Σ_j α_ji e_ji = W_e (Σ_j α_ji a_ji)`` per head, which moves ``W_e`` from every
edge to every destination node.
"""

from __future__ import annotations

import math

import torch
from torch_geometric.nn import TransformerConv


def dense_transformer_conv(
    conv: TransformerConv,
    x_src: torch.Tensor,
    x_dst: torch.Tensor,
    edge_attr: torch.Tensor,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """``conv`` on ``G`` complete bipartite graphs (module docstring).

    Args:
        conv: a ``TransformerConv`` with ``edge_dim``, ``concat=True``, ``root_weight=True``, no ``beta``.
        x_src: ``(G, S, F)`` source node features.
        x_dst: ``(G, D, F)`` destination node features.
        edge_attr: ``(G, S, D, E)`` attribute of edge ``j → i`` at ``[:, j, i]``.
        mask: ``(S, D)`` bool, True where the edge exists (``None``: all); every destination needs a source.

    Returns:
        ``(G, D, heads · C)`` the updated destination features.
    """
    if conv.lin_edge is None or conv.lin_edge.bias is not None or not conv.concat or not conv.root_weight \
            or conv.lin_beta is not None:
        raise ValueError("dense_transformer_conv needs a TransformerConv with edge_dim, concat, root_weight, no beta")
    graphs, sources, _ = x_src.shape
    destinations = x_dst.shape[1]
    heads, channels = conv.heads, conv.out_channels
    query = conv.lin_query(x_dst).view(graphs, destinations, heads, channels)
    key = conv.lin_key(x_src).view(graphs, sources, heads, channels)
    value = conv.lin_value(x_src).view(graphs, sources, heads, channels)
    edge_weight = conv.lin_edge.weight.view(heads, channels, -1)  # W_e per head: (H, C, E)
    query_attr = torch.einsum("gdhc,hce->gdhe", query, edge_weight)  # W_eᵀ q_i
    scores = torch.einsum("gdhc,gshc->gsdh", query, key) + torch.einsum("gdhe,gsde->gsdh", query_attr, edge_attr)
    scores = scores / math.sqrt(channels)
    if mask is not None:
        scores = scores.masked_fill(~mask[None, :, :, None], float("-inf"))
    alpha = torch.softmax(scores, dim=1)
    pooled_attr = torch.einsum("gsdh,gsde->gdhe", alpha, edge_attr)  # Σ_j α_ji a_ji
    out = torch.einsum("gsdh,gshc->gdhc", alpha, value) + torch.einsum("gdhe,hce->gdhc", pooled_attr, edge_weight)
    return out.reshape(graphs, destinations, heads * channels) + conv.lin_skip(x_dst)
