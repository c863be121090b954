"""The encode–process–decode graph network of FIGNet / FIGNet*, on already-normalized graphs.

Encode: one MLP for the nodes and one per edge set turn features into latents.
Process: `message_passing_steps` blocks with unshared weights (as in MeshGraphNets and FIGNet).
Each block first updates every edge set from the old node latents, then every node from the sum
of each edge set's messages into it, the sums concatenated in edge-set-name order:

    update_e  = MLP_e([edge latent, sender latent(s), receiver latent(s)])   (then LayerNorm)
    update_v  = MLP_v([node latent, Σ_in update_e for each edge set])         (then LayerNorm)
    edge latent += update_e;  node latent += update_v

The message an edge sends is its update (before the residual sum), as in MeshGraphNets.
Decode: an MLP without LayerNorm from each node latent to `output_size` numbers (the normalized
per-node acceleration).

Face–face hyper-edges (FIGNet): the edge latent has three parts of `latent_size`, part k
belonging to receiver vertex k (vertex order is canonical, set by the graph builder). One MLP
updates all three parts together from [edge latent (3L), the three sender vertex latents (3L),
the three receiver vertex latents (3L)], so part k is updated with sender vertex k and receiver
vertex k (and sees the rest of both faces); each part is layer-normalized on its own, added to
its part of the edge latent, and summed into receiver vertex k only. The message MLP is
therefore the edge-update MLP, with output 3·L, as for ordinary edges; a separate message MLP
would add a second MLP per block for no information the first lacks.

The blocks compute these equations without building the concatenations (`EdgeUpdate`,
`NodeUpdate`): a first layer's sender and receiver parts run once per distinct node and are
gathered per edge, and a node update's part for an edge set runs only on the nodes that
receive from it. The weights are the same; `concatenated_block_forward` is the literal form,
which the tests compare against. On a batch of 16 movi-b scenes this takes a third off the
network's time (docs/simulator.md, "Training throughput").
"""

from __future__ import annotations

import dataclasses

import torch
from torch import nn
from torch.nn import functional as F

from fignetctl.core.model.graph import (
    VERTICES_PER_FACE,
    EdgeSet,
    GraphSignature,
    MultiGraph,
    graph_signature,
)


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Sizes of the encode–process–decode network (defaults: the FIGNet / FIGNet* paper)."""

    latent_size: int = 128
    """Width of every node latent and edge latent (a face–face edge latent holds three)."""
    mlp_hidden_layers: int = 2
    """Hidden layers in every MLP (encoders, edge and node updates, decoder)."""
    mlp_hidden_size: int = 128
    """Width of every hidden layer."""
    message_passing_steps: int = 10
    """Processor blocks, each with its own weights."""
    output_size: int = 3
    """Numbers decoded per node: the normalized acceleration."""


PRESETS = {
    "paper": NetworkConfig(),
    "small": NetworkConfig(latent_size=64, mlp_hidden_size=64, message_passing_steps=5),
    "tiny": NetworkConfig(latent_size=32, mlp_hidden_size=32, message_passing_steps=2),
}


def build_mlp(input_size: int, hidden_size: int, hidden_layers: int, output_size: int) -> nn.Sequential:
    """Linear–ReLU hidden layers, then a linear output layer."""
    layers: list[nn.Module] = []
    layer_input_size = input_size
    for _ in range(hidden_layers):
        layers += [nn.Linear(layer_input_size, hidden_size), nn.ReLU()]
        layer_input_size = hidden_size
    layers.append(nn.Linear(layer_input_size, output_size))
    return nn.Sequential(*layers)


class PartwiseLayerNorm(nn.Module):
    """LayerNorm over each of `parts` consecutive chunks of `size`: (..., parts·size) -> same."""

    def __init__(self, parts: int, size: int):
        super().__init__()
        self.parts = parts
        self.size = size
        self.layer_norm = nn.LayerNorm(size)

    def forward(self, latents: torch.Tensor) -> torch.Tensor:
        chunked = latents.reshape(*latents.shape[:-1], self.parts, self.size)
        return self.layer_norm(chunked).reshape(latents.shape)


def build_mlp_with_layer_norm(input_size: int, output_parts: int, config: NetworkConfig) -> nn.Sequential:
    """An MLP to `output_parts` latents of config.latent_size, each layer-normalized."""
    mlp = build_mlp(
        input_size,
        config.mlp_hidden_size,
        config.mlp_hidden_layers,
        output_parts * config.latent_size,
    )
    return nn.Sequential(mlp, PartwiseLayerNorm(output_parts, config.latent_size))


def latent_parts(signature: GraphSignature, edge_set_name: str) -> int:
    """How many latents of latent_size one edge of this set carries: 3 for face–face, else 1."""
    return VERTICES_PER_FACE if edge_set_name in signature.hyper_edge_set_names else 1


def sum_messages_into_receivers(
    messages: torch.Tensor, receivers: torch.Tensor, num_nodes: int
) -> torch.Tensor:
    """Sum messages into their receiver nodes; nodes that receive nothing get zeros.

    messages : (E, L) with receivers (E,), or (E, 3, L) with receivers (E, 3): message
        [e, k] goes to node receivers[e, k]
    returns : (num_nodes, L); the size is given, never inferred from the largest index
    """
    latent_size = messages.shape[-1]
    summed = messages.new_zeros(num_nodes, latent_size)
    return summed.index_add_(0, receivers.reshape(-1), messages.reshape(-1, latent_size))


@dataclasses.dataclass(frozen=True)
class Incidence:
    """The distinct nodes one side of an edge set (its senders, or its receivers) names.

    A linear layer of a node's latent is then evaluated once per distinct node, not once per
    edge: face–face senders are a few hundred vertices for thousands of edges.

    nodes : (U,) the distinct node indices, ascending
    index : (E·parts,) for part k of edge e (flattened), its node's position in `nodes`
    rows : (E·parts,) index·parts + k: its row in a (U·parts, H) table of per-part projections
    parts : 3 for face–face, else 1
    """

    nodes: torch.Tensor
    index: torch.Tensor
    rows: torch.Tensor
    parts: int

    @classmethod
    def of(cls, indices: torch.Tensor) -> Incidence:
        """indices : (E,) or (E, 3) node indices, as an EdgeSet's senders or receivers."""
        nodes, inverse = torch.unique(indices, return_inverse=True)
        parts = indices.shape[1] if indices.dim() == 2 else 1
        rows = inverse.reshape(-1, parts) * parts + torch.arange(parts, device=indices.device)
        return cls(nodes, inverse.reshape(-1), rows.reshape(-1), parts)

    def gathered_projection(self, node_latents: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
        """weight @ [the latents of each edge's nodes, parts concatenated]: (E, H) for a weight
        (H, parts·L), as a linear layer on the gathered latents but with one product per node."""
        hidden, latent_size = weight.shape[0], node_latents.shape[1]
        per_part = weight.reshape(hidden, self.parts, latent_size).transpose(0, 1).reshape(-1, latent_size)
        table = node_latents.index_select(0, self.nodes) @ per_part.T  # (U, parts·H): node u, part k
        per_edge = table.reshape(-1, hidden).index_select(0, self.rows)
        return per_edge.reshape(-1, self.parts, hidden).sum(dim=1) if self.parts > 1 else per_edge


def edge_update_inputs(
    edge_latents: torch.Tensor, node_latents: torch.Tensor, edge_set: EdgeSet
) -> torch.Tensor:
    """[edge latent, sender latent(s), receiver latent(s)]: (E, 3L), or (E, 9L) for face–face."""
    return torch.cat(
        [edge_latents, gathered(node_latents, edge_set.senders), gathered(node_latents, edge_set.receivers)],
        dim=-1,
    )


def gathered(node_latents: torch.Tensor, nodes: torch.Tensor) -> torch.Tensor:
    """The latents of `nodes` (E,) or (E, 3), flattened to (E, L) or (E, 3L). index_select, not
    fancy indexing: its backward is a sum into rows (index_add), 2-3x faster on the CPU than
    fancy indexing's accumulating index_put."""
    width = node_latents.shape[1] * (nodes.shape[1] if nodes.dim() == 2 else 1)
    return node_latents.index_select(0, nodes.reshape(-1)).reshape(nodes.shape[0], width)


def after_first_layer(mlp_with_layer_norm: nn.Sequential, hidden: torch.Tensor) -> torch.Tensor:
    """The rest of a `build_mlp_with_layer_norm` MLP, given its first layer's output."""
    mlp, layer_norm = mlp_with_layer_norm
    for layer in list(mlp)[1:]:
        hidden = layer(hidden)
    return layer_norm(hidden)


class EdgeUpdate(nn.Sequential):
    """`build_mlp_with_layer_norm` on [edge latent, sender latent(s), receiver latent(s)],
    evaluated without building that concatenation: the first layer's edge part runs per edge,
    its sender and receiver parts once per distinct node (`Incidence`), gathered and added.
    `nn.Sequential.forward(self, edge_update_inputs(...))` computes the same."""

    def forward(self, edge_latents, node_latents, senders: Incidence, receivers: Incidence):
        first = self[0][0]
        edge_weight, sender_weight, receiver_weight = first.weight.split(edge_latents.shape[1], dim=1)
        hidden = F.linear(edge_latents, edge_weight, first.bias)
        hidden = hidden + senders.gathered_projection(node_latents, sender_weight)
        hidden = hidden + receivers.gathered_projection(node_latents, receiver_weight)
        return after_first_layer(self, hidden)


class NodeUpdate(nn.Sequential):
    """`build_mlp_with_layer_norm` on [node latent, Σ messages of each edge set], evaluated
    without building that concatenation: each edge set's part of the first layer runs only on
    the nodes that receive from it (the mesh nodes, the object nodes, the vertices in contact),
    and is added into their rows."""

    def forward(self, node_latents, summed_messages: list[tuple[torch.Tensor, torch.Tensor]]):
        """summed_messages : per edge set, (sums (U, L) into its distinct receivers, their nodes (U,))."""
        first = self[0][0]
        node_weight, *message_weights = first.weight.split(node_latents.shape[1], dim=1)
        hidden = F.linear(node_latents, node_weight, first.bias)
        for (sums, nodes), weight in zip(summed_messages, message_weights, strict=True):
            hidden = hidden.index_add(0, nodes, sums @ weight.T)
        return after_first_layer(self, hidden)


class GraphNetBlock(nn.Module):
    """One message-passing step: edge updates, then node update, both residual."""

    def __init__(self, config: NetworkConfig, signature: GraphSignature):
        super().__init__()
        latent_size = config.latent_size
        self.latent_size = latent_size
        self.edge_updates = nn.ModuleDict()
        for name in signature.edge_set_names:
            parts = latent_parts(signature, name)
            self.edge_updates[name] = EdgeUpdate(
                *build_mlp_with_layer_norm(3 * parts * latent_size, parts, config)
            )
        node_input_size = latent_size * (1 + len(signature.edge_set_names))
        self.node_update = NodeUpdate(*build_mlp_with_layer_norm(node_input_size, 1, config))

    def forward(
        self,
        node_latents: torch.Tensor,
        edge_latents: dict[str, torch.Tensor],
        incidences: dict[str, tuple[Incidence, Incidence]],
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """node_latents : (N, L); edge_latents : name -> (E, L) or (E, 3L); incidences : name ->
        (senders, receivers). Returns both latents updated."""
        new_edge_latents = {}
        summed_messages = []
        for name, edge_update in self.edge_updates.items():
            senders, receivers = incidences[name]
            update = edge_update(edge_latents[name], node_latents, senders, receivers)
            new_edge_latents[name] = edge_latents[name] + update
            messages = update.reshape(-1, self.latent_size)  # (E·parts, L)
            sums = sum_messages_into_receivers(messages, receivers.index, len(receivers.nodes))
            summed_messages.append((sums, receivers.nodes))
        return node_latents + self.node_update(node_latents, summed_messages), new_edge_latents


def concatenated_forward(model: EncodeProcessDecode, graph: MultiGraph) -> torch.Tensor:
    """`model(graph)` with every MLP on its concatenated input (`concatenated_block_forward`)."""
    node_latents = model.node_encoder(graph.node_features)
    edge_latents = {
        name: encoder(graph.edge_sets[name].features) for name, encoder in model.edge_encoders.items()
    }
    for block in model.processor:
        node_latents, edge_latents = concatenated_block_forward(block, node_latents, edge_latents, graph)
    return model.decoder(node_latents)


def concatenated_block_forward(
    block: GraphNetBlock, node_latents: torch.Tensor, edge_latents: dict[str, torch.Tensor], graph: MultiGraph
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """`GraphNetBlock.forward` as the module docstring writes it, each MLP on its concatenated
    input: the reference the block is tested against, and the training benchmark's baseline."""
    new_edge_latents = {}
    summed_messages = []
    for name, edge_update in block.edge_updates.items():
        edge_set = graph.edge_sets[name]
        update = nn.Sequential.forward(
            edge_update, edge_update_inputs(edge_latents[name], node_latents, edge_set)
        )
        new_edge_latents[name] = edge_latents[name] + update
        messages = update.reshape(*edge_set.receivers.shape, block.latent_size)
        summed_messages.append(sum_messages_into_receivers(messages, edge_set.receivers, graph.num_nodes))
    node_update = nn.Sequential.forward(
        block.node_update, torch.cat([node_latents, *summed_messages], dim=-1)
    )
    return node_latents + node_update, new_edge_latents


def silence(block: GraphNetBlock) -> None:
    """Zero the scale and shift of every LayerNorm in `block`, the last layer of each of its
    updates, so every update is exactly zero and the residual block passes its latents through
    unchanged. The scales still get gradients (those of the normalized MLP outputs), so training
    grows the block from there, as ReZero does (Bachlechner et al. 2020)."""
    for module in block.modules():
        if isinstance(module, PartwiseLayerNorm):
            nn.init.zeros_(module.layer_norm.weight)
            nn.init.zeros_(module.layer_norm.bias)


def mlp_widened(source: dict[str, torch.Tensor], target: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A network's weights `source` placed in the state dict `target` of the same network with
    wider MLP hidden layers (`mlp_hidden_size`), so that it computes exactly what `source` does.

    Each weight (o, i) of the source fills the top-left corner of the target's (O, I): the
    source's units keep their weights and read nothing of the added inputs (zeros), and the
    added units keep the target's random weights. An added hidden unit therefore computes
    something from the start, and its outgoing weights, zero, get gradients at once (unlike a
    silenced block, whose weights get none while its scale is zero). Widths other than the
    hidden ones (latents, inputs, outputs) are the same on both sides; names only one side has
    are left as they are, for `load_state_dict` to judge.
    """
    weights = {}
    for name, given in source.items():
        value = target.get(name)
        if value is None or given.shape == value.shape:
            weights[name] = given
            continue
        if given.dim() != value.dim() or any(g > v for g, v in zip(given.shape, value.shape, strict=True)):
            raise ValueError(f"{name}: {tuple(given.shape)} does not fit in {tuple(value.shape)}")
        grown = value.clone()
        rows = given.shape[0]
        if given.dim() == 2:
            grown[:rows] = 0
        grown[tuple(slice(0, n) for n in given.shape)] = given
        weights[name] = grown
    return weights


class EncodeProcessDecode(nn.Module):
    """Normalized graph -> per-node output (N, config.output_size).

    Built from a `GraphSignature` (feature widths and hyper-edge sets), so it has weights only
    for the edge sets it will see: a FIGNet* network has no node_node weights at all. Use
    `EncodeProcessDecode.for_graph(config, first_graph)` to take the widths from a graph.
    """

    def __init__(self, config: NetworkConfig, signature: GraphSignature):
        super().__init__()
        self.config = config
        self.signature = signature
        self.node_encoder = build_mlp_with_layer_norm(signature.node_feature_size, 1, config)
        self.edge_encoders = nn.ModuleDict()
        for name, feature_size in signature.edge_feature_sizes.items():
            self.edge_encoders[name] = build_mlp_with_layer_norm(
                feature_size, latent_parts(signature, name), config
            )
        self.processor = nn.ModuleList(
            GraphNetBlock(config, signature) for _ in range(config.message_passing_steps)
        )
        self.decoder = build_mlp(
            config.latent_size, config.mlp_hidden_size, config.mlp_hidden_layers, config.output_size
        )

    @classmethod
    def for_graph(cls, config: NetworkConfig, graph: MultiGraph) -> EncodeProcessDecode:
        return cls(config, graph_signature(graph))

    def forward(self, graph: MultiGraph) -> torch.Tensor:
        """graph : normalized MultiGraph matching self.signature. Returns (N, output_size)."""
        check_graph_matches_signature(graph, self.signature)
        node_latents = self.node_encoder(graph.node_features)
        edge_latents = {
            name: encoder(graph.edge_sets[name].features) for name, encoder in self.edge_encoders.items()
        }
        incidences = {
            name: (Incidence.of(edge_set.senders), Incidence.of(edge_set.receivers))
            for name, edge_set in graph.edge_sets.items()
        }
        for block in self.processor:
            node_latents, edge_latents = block(node_latents, edge_latents, incidences)
        return self.decoder(node_latents)


def check_graph_matches_signature(graph: MultiGraph, signature: GraphSignature) -> None:
    """Raise ValueError when a graph's edge sets or feature widths are not the network's."""
    found = graph_signature(graph)
    if set(found.edge_set_names) != set(signature.edge_set_names):
        raise ValueError(
            f"the network was built for edge sets {list(signature.edge_set_names)},"
            f" the graph has {list(found.edge_set_names)}"
        )
    if found != signature:
        raise ValueError(f"graph features {found.as_dict()} differ from the network's {signature.as_dict()}")
