"""Heterogeneous graph transformer (paper eq. 3, appendix C): the σ, φ and ψ networks.

One layer runs a PyG :class:`TransformerConv` with ``edge_dim`` per edge type (its own weights ``W₁ … W₅``: skip,
value, query, key and edge projections), sums the results per destination node type (:class:`HeteroConv`), then
applies ``LayerNorm(x + attention)`` and ``LayerNorm(h + MLP(h))`` per node type. Node types that receive no edge in
a layer keep their features.

``forward`` runs the layers on torch_geometric edge lists (:mod:`.sparse_graphs`). ``forward_dense`` runs the same
layers on graphs whose every edge type joins all source nodes of a graph to all its destination nodes (σ's local
graphs, ψ's graph; φ's graph through a :class:`DenseLayout` per edge type that reads its node tensors as such graphs),
in a dense batched layout (:mod:`.dense_attention`, :mod:`.dense_graphs`): the same weights and outputs, without
PyG's scatter operations. There, all the convs' projections that read one node type (query and skip
where it is the destination, key and value where it is the source) are one matrix product with their weights stacked,
done once per row when every graph holds the same nodes (an input expanded along the graphs). After
:meth:`HeteroGraphTransformer.compile_dense` the dense layers run through ``torch.compile`` wherever gradients are
recorded (training); the eager layers stay the path of sampling and the reference of the compiled one (tested equal).
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping

import torch
from torch import nn
from torch_geometric.nn import HeteroConv, TransformerConv

from .dense_attention import dense_attention
from .graph import EdgeType

Projection = tuple[EdgeType, str]  # (edge type, "query" | "key" | "value" | "skip"): a conv's ``lin_<role>``


class DenseLayout:
    """How one edge type's ``G`` graphs of the dense layout are read from its node types' tensors: as they are,
    ``(G, n, ·)`` (σ's local graphs, ψ's graph per sample); subclasses read other layouts (φ's, in
    :mod:`.dense_graphs`)."""

    def sources(self, x: torch.Tensor) -> torch.Tensor:
        """The source node type's tensor → ``(G, S, ·)``."""
        return x

    def destinations(self, x: torch.Tensor) -> torch.Tensor:
        """The destination node type's tensor → ``(G, D, ·)``."""
        return x

    def scatter(self, update: torch.Tensor, destination: torch.Tensor) -> torch.Tensor:
        """The attention's ``(G, D, ·)`` → the layout of the destination node type's tensor ``destination``."""
        return update


_AS_GIVEN = DenseLayout()


def projection_plan(edge_types: Iterable[EdgeType]) -> dict[str, list[Projection]]:
    """The projections that read each node type: key and value of the edge types it sends, query and skip of those it
    receives."""
    plan: dict[str, list[Projection]] = {}
    for edge_type in edge_types:
        source, _, destination = edge_type
        plan.setdefault(source, []).extend([(edge_type, "key"), (edge_type, "value")])
        plan.setdefault(destination, []).extend([(edge_type, "query"), (edge_type, "skip")])
    return plan


class HeteroGraphTransformerLayer(nn.Module):
    """One attention + MLP block over the edge types in ``edge_dims`` (edge type → attribute width)."""

    def __init__(self, edge_dims: Mapping[EdgeType, int], hidden_dim: int, num_heads: int, mlp_ratio: int):
        super().__init__()
        if hidden_dim % num_heads:
            raise ValueError(f"hidden_dim {hidden_dim} is not divisible by num_heads {num_heads}")
        with warnings.catch_warnings():
            # Source-only node types (e.g. scene nodes in σ's last layer) are intended: they only send messages.
            warnings.filterwarnings("ignore", message="There exist node types")
            self.attention = HeteroConv(
                {
                    edge_type: TransformerConv(hidden_dim, hidden_dim // num_heads, heads=num_heads, edge_dim=edge_dim)
                    for edge_type, edge_dim in edge_dims.items()
                },
                aggr="sum",
            )
        destinations = sorted({edge_type[2] for edge_type in edge_dims})
        self.attention_norm = nn.ModuleDict({node: nn.LayerNorm(hidden_dim) for node in destinations})
        self.mlp = nn.ModuleDict(
            {
                node: nn.Sequential(
                    nn.Linear(hidden_dim, mlp_ratio * hidden_dim), nn.GELU(), nn.Linear(mlp_ratio * hidden_dim, hidden_dim)
                )
                for node in destinations
            }
        )
        self.mlp_norm = nn.ModuleDict({node: nn.LayerNorm(hidden_dim) for node in destinations})
        self.projections = projection_plan(edge_dims)
        self._stacked: dict[str, tuple[torch.Tensor, torch.Tensor]] | None = None  # see fixed_weights

    def forward(
        self,
        x_dict: dict[str, torch.Tensor],
        edge_index_dict: dict[EdgeType, torch.Tensor],
        edge_attr_dict: dict[EdgeType, torch.Tensor],
    ) -> dict[str, torch.Tensor]:
        return self._update(x_dict, self.attention(x_dict, edge_index_dict, edge_attr_dict=edge_attr_dict))

    def forward_dense(
        self,
        x_dict: dict[str, torch.Tensor],
        edge_attr_dict: dict[EdgeType, torch.Tensor],
        mask_dict: Mapping[EdgeType, torch.Tensor | None],
        layout_dict: Mapping[EdgeType, DenseLayout] | None = None,
    ) -> dict[str, torch.Tensor]:
        """The layer on G complete graphs per edge type: ``x_dict`` node type → ``(G, n, H)``, or any ``(..., H)``
        that the edge type's :class:`DenseLayout` in ``layout_dict`` reads as ``(G, n, H)`` (absent: as
        given); ``edge_attr_dict`` edge type → ``(G, n_src / r, n_dst, E)`` (:func:`~.dense_attention.dense_attention`),
        ``mask_dict`` edge type → ``(n_src, n_dst)`` bool or ``None`` (all edges)."""
        layout_dict = layout_dict or {}
        projected = self._project(x_dict)
        attended: dict[str, torch.Tensor] = {}
        for edge_type, conv in self.attention.convs.items():
            destination = edge_type[2]
            layout = layout_dict.get(edge_type, _AS_GIVEN)
            skip = projected[edge_type, "skip"]
            update = layout.scatter(dense_attention(
                layout.destinations(projected[edge_type, "query"]), layout.sources(projected[edge_type, "key"]),
                layout.sources(projected[edge_type, "value"]), conv.lin_edge.weight, edge_attr_dict[edge_type],
                conv.heads, mask_dict[edge_type],
            ), skip) + skip
            attended[destination] = attended[destination] + update if destination in attended else update
        return self._update(x_dict, attended)

    def _project(self, x_dict: dict[str, torch.Tensor]) -> dict[Projection, torch.Tensor]:
        """Every projection of :attr:`projections`, one matrix product per node type: ``x_dict`` node type →
        ``(G, ..., H)`` gives ``(edge type, role)`` → ``(G, ..., H)``. A node type expanded along the graphs (stride 0)
        is projected once and expanded."""
        projected: dict[Projection, torch.Tensor] = {}
        for node, plan in self.projections.items():
            x = x_dict[node]
            shared = x.stride(0) == 0
            out = nn.functional.linear(x[:1] if shared else x, *self._stacked_projection(node))
            chunks = out.expand(*x.shape[:-1], out.shape[-1]).chunk(len(plan), dim=-1)
            projected.update(zip(plan, chunks))
        return projected

    def _stacked_projection(self, node: str) -> tuple[torch.Tensor, torch.Tensor]:
        """The weights ``(P · H, H)`` and biases ``(P · H,)`` of the ``P`` projections that read ``node``, stacked in
        the order of :attr:`projections`; stacked once per :func:`fixed_weights` block inside one."""
        if self._stacked is not None and node in self._stacked:
            return self._stacked[node]
        linears = [getattr(self.attention.convs[edge_type], f"lin_{role}") for edge_type, role in self.projections[node]]
        stacked = torch.cat([linear.weight for linear in linears]), torch.cat([linear.bias for linear in linears])
        if self._stacked is not None:
            self._stacked[node] = stacked
        return stacked

    def _update(self, x_dict: dict[str, torch.Tensor], attended: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        out = dict(x_dict)
        for node, update in attended.items():
            hidden = self.attention_norm[node](x_dict[node] + update)
            out[node] = self.mlp_norm[node](hidden + self.mlp[node](hidden))
        return out


class HeteroGraphTransformer(nn.Module):
    """A stack of :class:`HeteroGraphTransformerLayer` whose result is read at ``output_node_types`` only.

    The last layer keeps only the edge types that end at an output node type: updates of other node types there
    would never be read.
    """

    def __init__(
        self,
        edge_dims: Mapping[EdgeType, int],
        output_node_types: Iterable[str],
        num_layers: int,
        hidden_dim: int,
        num_heads: int,
        mlp_ratio: int,
    ):
        super().__init__()
        self.output_node_types = tuple(output_node_types)
        if num_layers < 1:
            raise ValueError(f"num_layers must be at least 1, got {num_layers}")
        last_dims = {edge_type: dim for edge_type, dim in edge_dims.items() if edge_type[2] in self.output_node_types}
        if not last_dims:
            raise ValueError(f"no edge type ends at the output node types {self.output_node_types}")
        self.layers = nn.ModuleList(
            HeteroGraphTransformerLayer(edge_dims if index < num_layers - 1 else last_dims, hidden_dim, num_heads, mlp_ratio)
            for index in range(num_layers)
        )
        self._compiled_dense: Callable[..., dict[str, torch.Tensor]] | None = None  # see compile_dense
        self._compile_training = self._compile_inference = False

    def forward(
        self,
        x_dict: dict[str, torch.Tensor],
        edge_index_dict: dict[EdgeType, torch.Tensor],
        edge_attr_dict: dict[EdgeType, torch.Tensor],
    ) -> dict[str, torch.Tensor]:
        """``x_dict``: node type → ``(num_nodes, hidden_dim)``; returns the output node types' features."""
        for layer in self.layers:
            x_dict = layer(x_dict, edge_index_dict, edge_attr_dict)
        return {node: x_dict[node] for node in self.output_node_types}

    def forward_dense(
        self,
        x_dict: dict[str, torch.Tensor],
        edge_attr_dict: dict[EdgeType, torch.Tensor],
        mask_dict: Mapping[EdgeType, torch.Tensor | None],
        layout_dict: Mapping[EdgeType, DenseLayout] | None = None,
    ) -> dict[str, torch.Tensor]:
        """:meth:`forward` on G complete graphs in the dense layout of :meth:`HeteroGraphTransformerLayer.forward_dense`.
        The attributes are laid out destination-major in memory (:mod:`.dense_attention`) and, under autocast, cast to
        its dtype once for every layer instead of at each of their matrix products (the same values). Compiled after
        :meth:`compile_dense` for the current grad mode."""
        grad = torch.is_grad_enabled()
        if self._compiled_dense is not None and (self._compile_training if grad else self._compile_inference):
            return self._compiled_dense(x_dict, edge_attr_dict, mask_dict, layout_dict)
        return self._forward_dense(x_dict, edge_attr_dict, mask_dict, layout_dict)

    def compile_dense(self, mode: str = "default", training: bool = True, inference: bool = False) -> None:
        """Run :meth:`forward_dense` through ``torch.compile(mode=mode, dynamic=False)`` where gradients are recorded
        (``training``: the training step) and/or where they are not (``inference``: DDIM sampling under
        ``inference_mode``); elsewhere the eager layers run. Compiling happens at the first call of each new input
        shape and grad mode (a new N or batch size): about 100 s for a training step of the small preset on 2 CPU
        cores, about 60 s for a control step."""
        self._compiled_dense = torch.compile(self._forward_dense, mode=mode, dynamic=False)
        self._compile_training, self._compile_inference = training, inference

    def _forward_dense(
        self,
        x_dict: dict[str, torch.Tensor],
        edge_attr_dict: dict[EdgeType, torch.Tensor],
        mask_dict: Mapping[EdgeType, torch.Tensor | None],
        layout_dict: Mapping[EdgeType, DenseLayout] | None = None,
    ) -> dict[str, torch.Tensor]:
        edge_attr_dict = {edge_type: _dense_attr_layout(attr) for edge_type, attr in edge_attr_dict.items()}
        for layer in self.layers:
            x_dict = layer.forward_dense(x_dict, edge_attr_dict, mask_dict, layout_dict)
        return {node: x_dict[node] for node in self.output_node_types}


@contextlib.contextmanager
def fixed_weights(module: nn.Module) -> Iterator[None]:
    """A block in which the weights of ``module`` do not change (one DDIM sampling, without gradients): its graph
    transformer layers stack each node type's projection weights once for the block instead of at every call."""
    layers = [layer for layer in module.modules() if isinstance(layer, HeteroGraphTransformerLayer)]
    for layer in layers:
        layer._stacked = {}
    try:
        yield
    finally:
        for layer in layers:
            layer._stacked = None


def _dense_attr_layout(attr: torch.Tensor) -> torch.Tensor:
    """``attr (G, S, D, E)`` destination-major in memory, in autocast's dtype where autocast is on (its matrix
    products would cast it there)."""
    if torch.is_autocast_enabled(attr.device.type) and attr.is_floating_point():
        attr = attr.to(torch.get_autocast_dtype(attr.device.type))
    return attr.transpose(1, 2).contiguous().transpose(1, 2)
