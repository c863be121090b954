"""Graph construction: two frames of a scene (t−1, t) -> the raw graph the simulator normalises.

Nodes, in this order:
1. the vertices of every dynamic object (all of them, in the scene's global vertex order),
2. the vertices of static objects that belong to a face in a collision pair this step
   (static geometry far from every moving object adds nothing),
3. one object node per dynamic object, at its centre of mass.

Node features (12): velocity x_t − x_{t−1} (3), kinematic displacement x_{t+1} − x_t of static
nodes (3, zero for dynamic ones), mass, friction, restitution, the static bit, and a node-type
one-hot (mesh, object).

Edge sets (all features relative, so translating the whole scene changes nothing):
- ``mesh_to_object`` / ``object_to_mesh`` (8): sender − receiver now (3) and its norm, sender −
  receiver in the rest shape (3) and its norm; dynamic objects only.
- ``node_node`` (8, FIGNet only): the same features along the surface-mesh edges.
- ``face_face`` (34, hyper-edges, both directions): between faces of different objects, not
  both static, within the collision radius (found with the broad phase). Features: receiver
  closest point − sender closest point (3) and its norm, the sender's three vertices relative
  to its closest point (9) and their norms (3), the same for the receiver (12), the sender's
  and receiver's unit normals (6). Each triangle's vertices are ordered canonically — by
  distance to its closest point, ties broken by coordinates — and the hyper-edge's senders and
  receivers list the vertex nodes in that order, so nothing depends on a face's vertex order.

Geometry is computed in float64 and only relative quantities are cast to float32.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from fignetctl.core.broadphase import face_pairs_within_radius
from fignetctl.core.model.graph import (
    FACE_FACE,
    MESH_TO_OBJECT,
    NODE_NODE,
    OBJECT_TO_MESH,
    EdgeSet,
    GraphSignature,
    MultiGraph,
)
from fignetctl.core.transforms import quat_to_matrix
from fignetctl.core.triangles import closest_points_triangles

NODE_FEATURE_SIZE = 12
RELATIVE_EDGE_FEATURE_SIZE = 8
FACE_FACE_FEATURE_SIZE = 34
# Relative resolution of the keys that order a triangle's vertices canonically.
ORDER_KEY_RESOLUTION = 1e-6


@dataclasses.dataclass(frozen=True)
class GraphConfig:
    """How a scene becomes a graph."""

    collision_radius: float = 0.2
    """Face pairs of different objects closer than this (metres) get face–face edges. At the
    30 fps of make-dataset a vertex moves up to ~0.4 m per frame (p99), so contact must be seen
    some way ahead; 0.2 m halves the edges of 0.4 m."""
    surface_edges: bool = False
    """True: FIGNet (node–node surface-mesh edges); False: FIGNet* (none)."""


def graph_signature_for(config: GraphConfig) -> GraphSignature:
    """The feature widths every graph built with `config` has."""
    sizes = {
        MESH_TO_OBJECT: RELATIVE_EDGE_FEATURE_SIZE,
        OBJECT_TO_MESH: RELATIVE_EDGE_FEATURE_SIZE,
        FACE_FACE: FACE_FACE_FEATURE_SIZE,
    }
    if config.surface_edges:
        sizes[NODE_NODE] = RELATIVE_EDGE_FEATURE_SIZE
    return GraphSignature(NODE_FEATURE_SIZE, sizes, (FACE_FACE,))


@dataclasses.dataclass
class SceneGeometry:
    """The meshes of one scene, concatenated; fixed for a whole trajectory.

    rest_vertices : (V, 3) float64, each object's scaled mesh in its object frame
    vertex_object : (V,) int64, the object of each vertex
    faces : (F, 3) int64, global vertex indices, counter-clockwise seen from outside
    face_object : (F,) int64
    static : (O,) bool
    properties : (O, 3) float64, mass, friction, restitution
    surface_edges : (S, 2) int64, each undirected mesh edge once (global vertex indices)
    """

    rest_vertices: np.ndarray
    vertex_object: np.ndarray
    faces: np.ndarray
    face_object: np.ndarray
    static: np.ndarray
    properties: np.ndarray
    surface_edges: np.ndarray

    @property
    def num_objects(self) -> int:
        return int(self.static.shape[0])

    @property
    def dynamic_vertices(self) -> np.ndarray:
        """(Vd,) the global indices of the vertices of dynamic objects, in order."""
        return np.flatnonzero(~self.static[self.vertex_object])

    def world_vertices(self, positions, quaternions):
        """positions (O, 3), quaternions (O, 4) w x y z -> (V, 3) float64 world vertices."""
        rotations = quat_to_matrix(np.asarray(quaternions, np.float64))[self.vertex_object]
        rotated = np.einsum("vij,vj->vi", rotations, self.rest_vertices)
        return rotated + np.asarray(positions, np.float64)[self.vertex_object]


def scene_geometry(meshes, scales, static, properties) -> SceneGeometry:
    """Concatenate per-object meshes into one SceneGeometry.

    meshes : O (vertices (V_o, 3), faces (F_o, 3)) pairs, unscaled, object frame
    scales : (O,), static : (O,) bool, properties : (O, 3) mass, friction, restitution
    """
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    rest = [np.asarray(v, np.float64) * float(s) for (v, _), s in zip(meshes, scales)]
    faces = [np.asarray(f, np.int64) + offset for (_, f), offset in zip(meshes, offsets)]
    vertex_object = np.repeat(np.arange(len(meshes)), [len(v) for v, _ in meshes])
    face_object = np.repeat(np.arange(len(meshes)), [len(f) for _, f in meshes])
    all_faces = np.concatenate(faces)
    return SceneGeometry(
        rest_vertices=np.concatenate(rest),
        vertex_object=vertex_object,
        faces=all_faces,
        face_object=face_object,
        static=np.asarray(static, bool),
        properties=np.asarray(properties, np.float64).reshape(len(meshes), 3),
        surface_edges=unique_undirected_edges(all_faces),
    )


def unique_undirected_edges(faces):
    """faces (F, 3) -> (S, 2) each mesh edge once, smaller index first."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(edges, axis=1), axis=0)


@dataclasses.dataclass
class SceneGraph:
    """A raw (unnormalised) graph and how its nodes map back to the scene.

    graph : MultiGraph with float32 features
    node_vertex : (N,) int64, the global vertex of each mesh node, −1 for object nodes
    num_dynamic_vertex_nodes : the first this many nodes are geometry.dynamic_vertices
    vertices : (3, V, 3) float64 world vertices of frames t−1, t, t+1 it was built from
    """

    graph: MultiGraph
    node_vertex: np.ndarray
    num_dynamic_vertex_nodes: int
    vertices: np.ndarray


def build_scene_graph(geometry, positions, quaternions, config) -> SceneGraph:
    """Object poses at t−1, t, t+1 -> the raw graph of step t.

    positions : (3, O, 3) float, quaternions : (3, O, 4) float w x y z, for frames t−1, t, t+1;
    frame t+1 is read only for static objects (their given motion); pass anything finite
    (e.g. frame t) for the dynamic ones.
    """
    positions = np.asarray(positions, np.float64)
    vertices = np.stack([geometry.world_vertices(p, q) for p, q in zip(positions, quaternions)])
    pair_i, pair_j = collision_face_pairs(geometry, vertices[1], config.collision_radius)
    node_vertex, node_object = select_nodes(geometry, pair_i, pair_j)
    node_history = np.stack(
        [node_positions(node_vertex, node_object, v, p) for v, p in zip(vertices, positions)]
    )
    vertex_to_node = np.full(len(geometry.rest_vertices), -1, np.int64)
    is_mesh_node = node_vertex >= 0
    vertex_to_node[node_vertex[is_mesh_node]] = np.flatnonzero(is_mesh_node)
    edge_sets = object_mesh_edge_sets(geometry, node_vertex, node_object, node_history[1])
    edge_sets[FACE_FACE] = face_face_edge_set(geometry, vertices[1], pair_i, pair_j, vertex_to_node)
    if config.surface_edges:
        edge_sets[NODE_NODE] = node_node_edge_set(geometry, vertices[1], vertex_to_node)
    node_features = node_feature_rows(geometry, node_vertex, node_object, node_history)
    graph = MultiGraph(torch.from_numpy(node_features), edge_sets)
    return SceneGraph(graph, node_vertex, len(geometry.dynamic_vertices), vertices)


def collision_face_pairs(geometry, vertices_now, radius):
    """(P,), (P,) face pairs of different objects, not both static, within `radius`."""
    triangles = np.asarray(vertices_now, np.float64)[geometry.faces]
    return face_pairs_within_radius(triangles, geometry.face_object, radius, geometry.static)


def select_nodes(geometry, pair_i, pair_j):
    """The graph's nodes: dynamic vertices, touched static vertices, dynamic object nodes.

    Returns node_vertex (N,) (−1 for object nodes) and node_object (N,).
    """
    dynamic_vertices = geometry.dynamic_vertices
    touched_faces = np.concatenate([pair_i, pair_j])
    touched_vertices = np.unique(geometry.faces[touched_faces].reshape(-1))
    static_vertices = touched_vertices[geometry.static[geometry.vertex_object[touched_vertices]]]
    dynamic_objects = np.flatnonzero(~geometry.static)
    node_vertex = np.concatenate([dynamic_vertices, static_vertices, np.full(len(dynamic_objects), -1)])
    node_object = np.concatenate(
        [geometry.vertex_object[dynamic_vertices], geometry.vertex_object[static_vertices], dynamic_objects]
    )
    return node_vertex.astype(np.int64), node_object.astype(np.int64)


def node_positions(node_vertex, node_object, vertices, centres):
    """(N, 3) positions of the nodes: vertices for mesh nodes, centres for object nodes."""
    is_mesh_node = node_vertex >= 0
    positions = np.asarray(centres, np.float64)[node_object]
    positions[is_mesh_node] = np.asarray(vertices, np.float64)[node_vertex[is_mesh_node]]
    return positions


def node_feature_rows(geometry, node_vertex, node_object, node_history):
    """node_history (3, N, 3) positions at t−1, t, t+1 -> (N, 12) float32 node features."""
    static = geometry.static[node_object]
    velocity = node_history[1] - node_history[0]
    kinematic_displacement = (node_history[2] - node_history[1]) * static[:, None]
    is_object_node = node_vertex < 0
    columns = [
        velocity,
        kinematic_displacement,
        geometry.properties[node_object],
        static[:, None],
        (~is_object_node)[:, None],
        is_object_node[:, None],
    ]
    return np.concatenate(columns, axis=1).astype(np.float32)


def relative_edge_features(sender_now, receiver_now, sender_rest, receiver_rest):
    """(E, 3) x4 -> (E, 8): sender − receiver now and at rest, each with its norm."""
    now = sender_now - receiver_now
    rest = sender_rest - receiver_rest
    norms = [np.linalg.norm(now, axis=1, keepdims=True), np.linalg.norm(rest, axis=1, keepdims=True)]
    return np.concatenate([now, norms[0], rest, norms[1]], axis=1).astype(np.float32)


def object_mesh_edge_sets(geometry, node_vertex, node_object, node_now):
    """The mesh_to_object and object_to_mesh edge sets of the dynamic objects."""
    dynamic_mesh_nodes = np.flatnonzero((node_vertex >= 0) & ~geometry.static[node_object])
    object_node_of = np.full(geometry.num_objects, -1, np.int64)
    object_nodes = np.flatnonzero(node_vertex < 0)
    object_node_of[node_object[object_nodes]] = object_nodes
    mesh, obj = dynamic_mesh_nodes, object_node_of[node_object[dynamic_mesh_nodes]]
    mesh_rest = geometry.rest_vertices[node_vertex[mesh]]
    object_rest = np.zeros_like(mesh_rest)
    mesh_to_object = relative_edge_features(node_now[mesh], node_now[obj], mesh_rest, object_rest)
    object_to_mesh = relative_edge_features(node_now[obj], node_now[mesh], object_rest, mesh_rest)
    return {
        MESH_TO_OBJECT: _edge_set(MESH_TO_OBJECT, mesh_to_object, mesh, obj),
        OBJECT_TO_MESH: _edge_set(OBJECT_TO_MESH, object_to_mesh, obj, mesh),
    }


def node_node_edge_set(geometry, vertices_now, vertex_to_node):
    """FIGNet's surface-mesh edges, both directions, between mesh nodes in the graph."""
    edges = geometry.surface_edges
    edges = edges[(vertex_to_node[edges] >= 0).all(axis=1)]
    edges = np.concatenate([edges, edges[:, ::-1]])
    senders, receivers = edges[:, 0], edges[:, 1]
    features = relative_edge_features(
        vertices_now[senders],
        vertices_now[receivers],
        geometry.rest_vertices[senders],
        geometry.rest_vertices[receivers],
    )
    return _edge_set(NODE_NODE, features, vertex_to_node[senders], vertex_to_node[receivers])


def face_face_edge_set(geometry, vertices_now, pair_i, pair_j, vertex_to_node):
    """Collision hyper-edges for the face pairs, in both directions."""
    sender_faces = np.concatenate([pair_i, pair_j])
    receiver_faces = np.concatenate([pair_j, pair_i])
    vertices_now = np.asarray(vertices_now, np.float64)
    features, sender_order, receiver_order = face_face_features(
        vertices_now[geometry.faces[sender_faces]], vertices_now[geometry.faces[receiver_faces]]
    )
    senders = np.take_along_axis(geometry.faces[sender_faces], sender_order, axis=1)
    receivers = np.take_along_axis(geometry.faces[receiver_faces], receiver_order, axis=1)
    return _edge_set(FACE_FACE, features, vertex_to_node[senders], vertex_to_node[receivers])


def face_face_features(sender_triangles, receiver_triangles):
    """(E, 3, 3) x2 -> features (E, 34) float32, sender_order (E, 3), receiver_order (E, 3).

    The orders give each triangle's vertices canonically (see the module docstring).
    """
    sender_point, receiver_point, distance = closest_points_triangles(sender_triangles, receiver_triangles)
    sender_order = canonical_vertex_order(sender_triangles, sender_point)
    receiver_order = canonical_vertex_order(receiver_triangles, receiver_point)
    sender_relative = _ordered(sender_triangles, sender_order) - sender_point[:, None]
    receiver_relative = _ordered(receiver_triangles, receiver_order) - receiver_point[:, None]
    columns = [
        receiver_point - sender_point,
        distance[:, None],
        sender_relative.reshape(-1, 9),
        np.linalg.norm(sender_relative, axis=2),
        receiver_relative.reshape(-1, 9),
        np.linalg.norm(receiver_relative, axis=2),
        unit_normals(sender_triangles),
        unit_normals(receiver_triangles),
    ]
    features = np.concatenate(columns, axis=1).astype(np.float32)
    return features, sender_order, receiver_order


def canonical_vertex_order(triangles, points):
    """(E, 3, 3), (E, 3) -> (E, 3): vertex order by distance to the point, ties by coordinates.

    Keys are rounded to 1e-6 of the triangle's size first, so vertices that are equally far
    in exact arithmetic (a square face resting on the floor) are ordered by their coordinates
    rather than by rounding noise, which differs when the scene is translated.
    """
    relative = triangles - points[:, None]
    distance = np.linalg.norm(relative, axis=2)
    resolution = ORDER_KEY_RESOLUTION * np.maximum(distance.max(axis=1, keepdims=True), 1e-300)
    quantized = np.round(np.concatenate([relative, distance[..., None]], axis=2) / resolution[..., None])
    keys = (quantized[..., 2], quantized[..., 1], quantized[..., 0], quantized[..., 3])
    return np.lexsort(keys, axis=-1)


def _ordered(triangles, order):
    return np.take_along_axis(triangles, order[..., None], axis=1)


def unit_normals(triangles):
    """(E, 3, 3) -> (E, 3) unit normals (right-hand rule); zero for zero-area triangles."""
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 1e-300)


def _edge_set(name, features, senders, receivers):
    return EdgeSet(
        name,
        torch.from_numpy(np.ascontiguousarray(features, np.float32)),
        torch.from_numpy(np.ascontiguousarray(senders, np.int64)),
        torch.from_numpy(np.ascontiguousarray(receivers, np.int64)),
    )
