"""The graphs the learned network reads: one node set and named edge sets.

One node set. Mesh nodes (one per vertex) and object nodes (one per object, at its centre of
mass) share one index space, as in FIGNet: every edge set indexes the same `node_features`
rows, and the graph builder puts a node-type one-hot (mesh, object) into the features. One
index space keeps batching to a single offset per graph and lets a face–face edge name its six
vertices directly; the cost is that mesh and object nodes share the node encoder and update
MLPs, which the one-hot tells apart.

Edge sets, by name (the builder emits every set its model uses, empty ones included, so
batches of graphs agree on names and widths):

- ``mesh_to_object``, ``object_to_mesh``: ordinary edges, senders and receivers ``(E,)``.
- ``node_node``: surface-mesh edges, ordinary; FIGNet only, absent in FIGNet*.
- ``face_face``: collision hyper-edges between faces of different objects. Senders ``(E, 3)``
  are the sender face's three vertex nodes, receivers ``(E, 3)`` the receiver face's, each in
  the builder's canonical vertex order; column k of senders and of receivers is "vertex k".

The network learns nothing about names except through `GraphSignature`, which records the
feature widths and which sets are hyper-edges; an edge set is a hyper-edge set when its
senders have shape ``(E, 3)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import torch

MESH_TO_OBJECT = "mesh_to_object"
OBJECT_TO_MESH = "object_to_mesh"
NODE_NODE = "node_node"
FACE_FACE = "face_face"
VERTICES_PER_FACE = 3


@dataclasses.dataclass
class EdgeSet:
    """One named edge type.

    features : (E, F_e) float
    senders : (E,) long, or (E, 3) long for hyper-edges (the sender face's vertex nodes)
    receivers : same shape as senders (for hyper-edges, the receiver face's vertex nodes)
    """

    name: str
    features: torch.Tensor
    senders: torch.Tensor
    receivers: torch.Tensor

    def __post_init__(self) -> None:
        check_edge_set_shapes(self)

    @property
    def num_edges(self) -> int:
        return self.features.shape[0]

    @property
    def is_hyper_edge_set(self) -> bool:
        """True when each edge joins a face of 3 sender nodes to a face of 3 receiver nodes."""
        return self.senders.dim() == 2

    def to(self, device: torch.device | str) -> EdgeSet:
        return EdgeSet(
            self.name,
            self.features.to(device),
            self.senders.to(device),
            self.receivers.to(device),
        )


def check_edge_set_shapes(edge_set: EdgeSet) -> None:
    """Raise ValueError, naming the edge set, when its tensors do not fit together."""
    name = edge_set.name
    if edge_set.features.dim() != 2:
        raise ValueError(f"edge set {name!r}: features must be (E, F), got {tuple(edge_set.features.shape)}")
    if edge_set.senders.shape != edge_set.receivers.shape:
        raise ValueError(f"edge set {name!r}: senders and receivers differ in shape")
    if edge_set.senders.dtype != torch.long or edge_set.receivers.dtype != torch.long:
        raise ValueError(f"edge set {name!r}: senders and receivers must be torch.long")
    index_shape = tuple(edge_set.senders.shape)
    ordinary = len(index_shape) == 1
    hyper = len(index_shape) == 2 and index_shape[1] == VERTICES_PER_FACE
    if not (ordinary or hyper) or index_shape[0] != edge_set.features.shape[0]:
        raise ValueError(
            f"edge set {name!r}: senders must be (E,) or (E, 3) with E ="
            f" {edge_set.features.shape[0]} feature rows, got {index_shape}"
        )


@dataclasses.dataclass
class MultiGraph:
    """Nodes and named edge sets, already normalized.

    node_features : (N, F_n) float, mesh and object nodes in one index space
    edge_sets : name -> EdgeSet, each indexing rows of node_features
    """

    node_features: torch.Tensor
    edge_sets: dict[str, EdgeSet]

    def __post_init__(self) -> None:
        if self.node_features.dim() != 2:
            raise ValueError(f"node_features must be (N, F), got {tuple(self.node_features.shape)}")
        for name, edge_set in self.edge_sets.items():
            if name != edge_set.name:
                raise ValueError(f"edge set stored under {name!r} is named {edge_set.name!r}")

    @property
    def num_nodes(self) -> int:
        return self.node_features.shape[0]

    def to(self, device: torch.device | str) -> MultiGraph:
        edge_sets = {name: edge_set.to(device) for name, edge_set in self.edge_sets.items()}
        return MultiGraph(self.node_features.to(device), edge_sets)


@dataclasses.dataclass(frozen=True)
class GraphSignature:
    """What the network's encoders expect; fixed when the network is built, saved with it.

    node_feature_size : F_n, the width of node_features
    edge_feature_sizes : edge set name -> F_e, sorted by name
    hyper_edge_set_names : the edge sets whose senders and receivers are (E, 3) faces
    """

    node_feature_size: int
    edge_feature_sizes: dict[str, int]
    hyper_edge_set_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        sorted_sizes = dict(sorted(self.edge_feature_sizes.items()))
        object.__setattr__(self, "edge_feature_sizes", sorted_sizes)
        object.__setattr__(self, "hyper_edge_set_names", tuple(sorted(self.hyper_edge_set_names)))
        unknown = set(self.hyper_edge_set_names) - set(sorted_sizes)
        if unknown:
            raise ValueError(f"hyper-edge sets {sorted(unknown)} have no feature size")

    @property
    def edge_set_names(self) -> tuple[str, ...]:
        return tuple(self.edge_feature_sizes)

    def as_dict(self) -> dict:
        """Plain values, for writing next to the weights (nothing is pickled)."""
        return dataclasses.asdict(self)


def graph_signature(graph: MultiGraph) -> GraphSignature:
    """The signature of one graph: build the network from the first graph a dataset gives."""
    return GraphSignature(
        node_feature_size=graph.node_features.shape[1],
        edge_feature_sizes={name: es.features.shape[1] for name, es in graph.edge_sets.items()},
        hyper_edge_set_names=tuple(name for name, es in graph.edge_sets.items() if es.is_hyper_edge_set),
    )


def batch_graphs(graphs: Sequence[MultiGraph]) -> MultiGraph:
    """One graph holding several, disconnected: nodes concatenated in list order, edge indices
    offset by the number of nodes before their graph.

    Per-node tensors (targets, masks) batch the same way, with `torch.cat`; split the network's
    output back with `torch.split(output, [g.num_nodes for g in graphs])`.
    """
    if not graphs:
        raise ValueError("batch_graphs needs at least one graph")
    names = list(graphs[0].edge_sets)
    for graph in graphs[1:]:
        if sorted(graph.edge_sets) != sorted(names):
            raise ValueError(f"graphs disagree on edge sets: {sorted(names)} vs {sorted(graph.edge_sets)}")
    node_counts = torch.tensor([graph.num_nodes for graph in graphs])
    offsets = (torch.cumsum(node_counts, 0) - node_counts).tolist()
    edge_sets = {name: batch_edge_sets([g.edge_sets[name] for g in graphs], offsets) for name in names}
    node_features = torch.cat([graph.node_features for graph in graphs], dim=0)
    return MultiGraph(node_features, edge_sets)


def batch_edge_sets(edge_sets: Sequence[EdgeSet], node_offsets: Sequence[int]) -> EdgeSet:
    """Concatenate one named edge set from several graphs, shifting indices by node_offsets."""
    senders = [es.senders + offset for es, offset in zip(edge_sets, node_offsets, strict=True)]
    receivers = [es.receivers + offset for es, offset in zip(edge_sets, node_offsets, strict=True)]
    return EdgeSet(
        name=edge_sets[0].name,
        features=torch.cat([es.features for es in edge_sets], dim=0),
        senders=torch.cat(senders, dim=0),
        receivers=torch.cat(receivers, dim=0),
    )
