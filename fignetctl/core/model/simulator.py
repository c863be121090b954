"""The learned simulator around the network: features in, rigid poses out.

Three layers, as in learning_to_simulate: `EncodeProcessDecode` (network.py) sees only
normalised graphs; `LearnedSimulator` here builds and normalises graphs (`preprocess`), turns
the network's normalised accelerations into next positions (`postprocess`), and makes training
targets (`inverse_postprocess`); noise comes from noise.py and is passed in.

One step reads like the paper:

    scene_graph = build_scene_graph(geometry, positions, quaternions, config.graph)
    normalized_acceleration = self.network(self.preprocess(scene_graph.graph))
    next_vertices = self.postprocess(normalized_acceleration, vertices_previous, vertices_now)
    next_pose = shape_match(rest shape -> next_vertices)   # rigid, never a reflection
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import torch
from torch import nn

from fignetctl.core.model.graph import EdgeSet, MultiGraph
from fignetctl.core.model.network import PRESETS as NETWORK_PRESETS
from fignetctl.core.model.network import EncodeProcessDecode, NetworkConfig
from fignetctl.core.model.normalizer import Normalizer
from fignetctl.core.model.scene_graph import (
    NODE_FEATURE_SIZE,
    GraphConfig,
    build_scene_graph,
    graph_signature_for,
)
from fignetctl.core.shape_matching import fit_rigid_transform
from fignetctl.core.transforms import matrix_to_quat, quat_conjugate, quat_multiply, quat_normalize

# Floor of every normaliser's std: features are in metres (per step) and material units, so a
# spread below a micrometre is float rounding, which must not be blown up into signal.
STD_EPSILON = 1e-6


@dataclasses.dataclass(frozen=True)
class SimulatorConfig:
    """Everything that defines a learned simulator's inputs and network."""

    network: NetworkConfig = NETWORK_PRESETS["small"]
    """Sizes of the encode–process–decode network."""
    graph: GraphConfig = GraphConfig()
    """Collision radius and FIGNet (surface edges) or FIGNet* (none)."""
    max_faces_per_object: int | None = 256
    """Dynamic objects' meshes are decimated (quadric error) to at most this many faces; None
    keeps them. Static meshes are kept whole (scene_data.py)."""
    max_static_edge: float | None = None
    """Static meshes are subdivided until no edge is longer than this (m); None keeps them.
    The face–face features hold each face's vertices relative to its closest point, so one
    80 m floor triangle beside 0.1 m object triangles would set the normaliser's scale to
    tens of metres and hide the object's contact geometry. Subdividing the floor to 1 m (the
    v2 retraining) fixed that at 2.8x the face-face edges; clamping the offsets
    (`GraphConfig.max_vertex_offset`, the default now) fixes it with none."""

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "SimulatorConfig":
        values = json.loads(text)
        graph = {"max_vertex_offset": None, **values["graph"]}  # absent: a model file older than the field
        return cls(
            network=NetworkConfig(**values["network"]),
            graph=GraphConfig(**graph),
            max_faces_per_object=values["max_faces_per_object"],
            max_static_edge=values.get("max_static_edge"),  # absent: a model trained without
        )


class LearnedSimulator(nn.Module):
    """Normalisers and the network; predicts the next world vertices of dynamic objects."""

    def __init__(self, config: SimulatorConfig):
        super().__init__()
        self.config = config
        signature = graph_signature_for(config.graph)
        self.network = EncodeProcessDecode(config.network, signature)
        self.node_normalizer = Normalizer(NODE_FEATURE_SIZE, std_epsilon=STD_EPSILON)
        self.edge_normalizers = nn.ModuleDict(
            {name: Normalizer(size, std_epsilon=STD_EPSILON) for name, size in signature.edge_feature_sizes.items()}
        )
        self.acceleration_normalizer = Normalizer(3, std_epsilon=STD_EPSILON)
        self.trained_properties = None  # ranges of the training data's properties (properties.py)

    def preprocess(self, graph: MultiGraph, accumulate: bool) -> MultiGraph:
        """Raw graph -> normalised graph (statistics updated when `accumulate`)."""
        nodes = self.node_normalizer(graph.node_features, accumulate)
        edge_sets = {
            name: self._normalised_edge_set(edge_set, accumulate)
            for name, edge_set in graph.edge_sets.items()
        }
        return MultiGraph(nodes, edge_sets)

    def _normalised_edge_set(self, edge_set: EdgeSet, accumulate: bool) -> EdgeSet:
        normalizer = self.edge_normalizers[edge_set.name]
        accumulate = accumulate and edge_set.num_edges > 0
        if normalizer.count.item() == 0 and not accumulate:
            return edge_set  # an edge type never seen in training: no statistics to apply
        features = normalizer(edge_set.features, accumulate)
        return EdgeSet(edge_set.name, features, edge_set.senders, edge_set.receivers)

    def forward(self, graph: MultiGraph, accumulate: bool = False) -> torch.Tensor:
        """Raw graph -> (N, 3) normalised per-node accelerations."""
        return self.network(self.preprocess(graph, accumulate))

    def inverse_postprocess(self, acceleration: torch.Tensor, accumulate: bool) -> torch.Tensor:
        """(n, 3) accelerations in metres per step² -> normalised training targets."""
        return self.acceleration_normalizer(acceleration, accumulate)

    def postprocess(self, normalized_acceleration, vertices_previous, vertices_now):
        """Integrate x_{t+1} = x_t + (x_t − x_{t−1}) + a; all (n, 3), float64 numpy out."""
        acceleration = self.acceleration_normalizer.inverse(normalized_acceleration)
        acceleration = acceleration.detach().cpu().double().numpy()
        return 2.0 * vertices_now - vertices_previous + acceleration

    @torch.no_grad()
    def step(self, geometry, positions, quaternions, free_flight=None):
        """Predict the poses of frame t+1.

        positions (3, O, 3), quaternions (3, O, 4): frames t−1, t, t+1; frame t+1 is read for
        static objects only. Returns next positions (O, 3) and quaternions (O, 4), float64,
        with static objects taken from frame t+1.

        free_flight : None, or gravity · dt² (3,) in metres per step²: a dynamic object with no
            face within the collision radius of another object's face has no edge to anything
            outside itself, so physics leaves one answer for it, free flight
            (`free_flight_poses`), which is then used instead of the network's; when no object
            touches anything the network is not run.
        """
        scene_graph = build_scene_graph(geometry, positions, quaternions, self.config.graph)
        flying = None
        if free_flight is not None:
            flying = ~geometry.static & ~scene_graph.touching
            flown = free_flight_poses(positions[:2], quaternions[:2], free_flight)
            if np.array_equal(flying, ~geometry.static):  # nothing touches anything
                return (np.where(flying[:, None], flown[0], positions[2]).astype(np.float64),
                        np.where(flying[:, None], flown[1], quaternions[2]).astype(np.float64))
        device = next(self.parameters()).device
        normalized = self(scene_graph.graph.to(device))[: scene_graph.num_dynamic_vertex_nodes]
        previous, now = scene_graph.dynamic_vertex_positions[:2]
        next_vertices = self.postprocess(normalized, previous, now)
        next_positions, next_quaternions = rigid_poses_from_vertices(geometry, next_vertices, positions[2], quaternions[2])
        if flying is not None:
            next_positions[flying], next_quaternions[flying] = flown[0][flying], flown[1][flying]
        return next_positions, next_quaternions


def free_flight_poses(positions, quaternions, acceleration):
    """Poses at t+1 of rigid bodies in free flight: constant acceleration of the centre,
    constant angular velocity (PyBullet's rigid bodies have no gyroscopic term here: one
    step of this matches its free-flight frames to 2.4e-7 m, median; docs/simulator.md).

    positions (2, O, 3), quaternions (2, O, 4): frames t−1, t; acceleration (3,) m/step²
    returns (O, 3), (O, 4) float64
    """
    positions = np.asarray(positions, np.float64)
    quaternions = np.asarray(quaternions, np.float64)
    next_positions = 2.0 * positions[1] - positions[0] + np.asarray(acceleration, np.float64)
    turn = quat_multiply(quaternions[1], quat_conjugate(quaternions[0]))
    return next_positions, quat_normalize(quat_multiply(turn, quaternions[1]))


def rigid_poses_from_vertices(geometry, dynamic_vertex_positions, static_positions, static_quaternions):
    """Shape-match each dynamic object's rest mesh onto its predicted vertices.

    dynamic_vertex_positions : (Vd, 3), rows of geometry.dynamic_vertices
    static_positions (O, 3), static_quaternions (O, 4): poses used for static objects
    returns positions (O, 3), quaternions (O, 4) float64
    """
    positions = np.array(static_positions, np.float64)
    quaternions = np.array(static_quaternions, np.float64)
    dynamic = geometry.dynamic_vertices
    owner = geometry.vertex_object[dynamic]
    for obj in np.flatnonzero(~geometry.static):
        rows = owner == obj
        rotation, translation = fit_rigid_transform(geometry.rest_vertices[dynamic[rows]], dynamic_vertex_positions[rows])
        positions[obj] = translation
        quaternions[obj] = matrix_to_quat(rotation)
    return positions, quaternions
