"""A PyG :class:`TransformerConv` evaluated densely on many small graphs whose edges join every source node to every
destination node (the local graphs of σ): the same weights and the same maths, without scatter operations.

For ``G`` graphs, each with ``S`` source and ``D`` destination nodes, and the edge ``j → i`` present where
``mask[j, i]``, the layer computes per head ``h`` (width ``C``), with the conv's own linear maps (paper eq. 3)::

    q_i = W_q x_i,   k_j = W_k x_j,   v_j = W_v x_j,   e_ji = W_e a_ji
    α_ji = softmax_j( q_i · (k_j + e_ji) / √C )          (over the sources j of i)
    x'_i = W_skip x_i + ‖_h Σ_j α_ji (v_j + e_ji)

which is exactly ``TransformerConv(heads=H, concat=True, root_weight=True, beta=False, dropout=0)`` on the same
graph (tested against it). Dense layout: ``x_src (G, S, F)``, ``x_dst (G, D, F)``, ``edge_attr (G, S, D, E)``, or
``(G, S / r, D, E)`` when ``r`` consecutive sources share their attributes (ψ: the keypoints of one frame), which
scores and pools each shared attribute once.

``W_e`` is linear without bias, so the per-edge projections ``e_ji`` (``G·S·D·H·C`` numbers) are never formed:
``q_i · e_ji = (W_eᵀ q_i) · a_ji`` and ``Σ_j α_ji e_ji = W_e (Σ_j α_ji a_ji)`` per head, which moves ``W_e`` from every
edge to every destination node.

Every product is one batched matrix product: the scores are laid out ``(G, D, H, S)`` (softmax over the last axis),
and the attributes are read destination-major, ``edge_attr.transpose(1, 2)`` ``(G, D, S, E)``, which costs no copy
when they were built in that memory layout (:func:`~.dense_graphs.dense_position_attr` and
:func:`~.dense_graphs.dense_transform_attr` do).
"""

from __future__ import annotations

import math

import torch
from torch_geometric.nn import TransformerConv


def check_dense_conv(conv: TransformerConv) -> None:
    """Raise ``ValueError`` unless ``conv`` is a ``TransformerConv`` that :func:`dense_attention` computes: with
    ``edge_dim``, ``concat=True``, ``root_weight=True``, no ``beta``."""
    if conv.lin_edge is None or conv.lin_edge.bias is not None or not conv.concat or not conv.root_weight \
            or conv.lin_beta is not None:
        raise ValueError("dense_transformer_conv needs a TransformerConv with edge_dim, concat, root_weight, no beta")


def dense_attention(
    query: torch.Tensor,
    key: torch.Tensor,
    value: torch.Tensor,
    edge_weight: torch.Tensor,
    edge_attr: torch.Tensor,
    heads: int,
    mask: torch.Tensor | None = None,
) -> torch.Tensor:
    """The attention part of the layer (module docstring) from the projected nodes, without the skip term.

    Args:
        query: ``(G, D, H · C)`` projected destination nodes ``W_q x_i``.
        key: ``(G, S, H · C)`` and ``value``: ``(G, S, H · C)``, projected source nodes ``W_k x_j``, ``W_v x_j``.
        edge_weight: ``(H · C, E)`` the edge projection ``W_e``.
        edge_attr: ``(G, S / r, D, E)``: the attribute of edge ``j → i`` at ``[:, j // r, i]``, shared by ``r``
            consecutive sources (``r = 1``: one per edge; ψ's keypoints of one source frame share theirs).
        heads: ``H``.
        mask: ``(S, D)`` bool, True where the edge exists (``None``: all); every destination needs a source.

    Returns:
        ``(G, D, H · C)``: ``‖_h Σ_j α_ji (v_j + e_ji)``.
    """
    graphs, destinations, width = query.shape
    sources, channels, edge_dim = key.shape[1], width // heads, edge_attr.shape[-1]
    attr_sources = edge_attr.shape[1]
    shared = sources // attr_sources  # r
    query = query.view(graphs, destinations, heads, channels)
    key = key.view(graphs, sources, heads, channels)
    value = value.view(graphs, sources, heads, channels)
    weight = edge_weight.view(heads, channels, edge_dim)  # W_e per head
    attr = edge_attr.transpose(1, 2)  # (G, D, S / r, E)
    heads_first = query.permute(2, 0, 1, 3).reshape(heads, graphs * destinations, channels)
    query_attr = torch.bmm(heads_first, weight).view(heads, graphs, destinations, edge_dim)  # W_eᵀ q_i
    attr_scores = torch.matmul(query_attr.permute(1, 2, 0, 3), attr.transpose(-1, -2))  # (G, D, H, S / r)
    scores = torch.matmul(query.transpose(1, 2), key.permute(0, 2, 3, 1)).transpose(1, 2)  # (G, D, H, S)
    if shared > 1:
        scores = scores.view(graphs, destinations, heads, attr_sources, shared) + attr_scores[..., None]
        scores = scores.view(graphs, destinations, heads, sources)
    else:
        scores = scores + attr_scores
    scores = scores / math.sqrt(channels)
    if mask is not None:
        scores = scores.masked_fill(~mask.t()[:, None, :], float("-inf"))
    alpha = torch.softmax(scores, dim=-1)  # (G, D, H, S)
    alpha_per_attr = alpha.view(graphs, destinations, heads, attr_sources, shared).sum(-1) if shared > 1 else alpha
    pooled_attr = torch.matmul(alpha_per_attr, attr)  # Σ_j α_ji a_ji: (G, D, H, E)
    pooled_attr = pooled_attr.permute(2, 0, 1, 3).reshape(heads, graphs * destinations, edge_dim)
    attr_out = torch.bmm(pooled_attr, weight.transpose(1, 2)).view(heads, graphs, destinations, channels)
    value_out = torch.matmul(alpha.transpose(1, 2), value.transpose(1, 2))  # (G, H, D, C)
    out = value_out.permute(0, 2, 1, 3) + attr_out.permute(1, 2, 0, 3)
    return out.reshape(graphs, destinations, width)


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
        edge_attr: ``(G, S / r, D, E)`` attribute of edge ``j → i`` at ``[:, j // r, i]`` (:func:`dense_attention`).
        mask: ``(S, D)`` bool, True where the edge exists (``None``: all); every destination needs a source.

    Returns:
        ``(G, D, heads · C)`` the updated destination features.
    """
    check_dense_conv(conv)
    attended = dense_attention(
        conv.lin_query(x_dst), conv.lin_key(x_src), conv.lin_value(x_src), conv.lin_edge.weight, edge_attr,
        conv.heads, mask,
    )
    return attended + conv.lin_skip(x_dst)
