"""Graph construction: two frames of a scene (t−1, t) -> the raw graph the simulator normalizes.

Nodes, in this order:
1. the vertices of every dynamic object (all of them, in the scene's global vertex order),
2. the vertices of static objects that belong to a face in a collision pair this step
   (static geometry far from every moving object adds nothing),
3. one object node per dynamic object, at its centre of mass.

Node features (12): velocity x_t − x_{t−1} (3; for a velocity state, each dynamic point's
instantaneous velocity (v + ω × (x − c)) times dt), kinematic displacement x_{t+1} − x_t of static
nodes (3, zero for dynamic ones), mass (kg, or its logarithm with `GraphConfig.log_mass`),
friction, restitution, the static bit, and a node-type
one-hot (mesh, object). With `GraphConfig.inertia`, 9 more: an object node's inertia tensor per
unit mass about its centre in the world frame, R G Rᵀ (row-major; zeros on mesh nodes).

Edge sets (all features relative, so translating the whole scene changes nothing):
- ``mesh_to_object`` / ``object_to_mesh`` (8): sender − receiver now (3) and its norm, sender −
  receiver in the rest shape (3) and its norm; dynamic objects only.
- ``node_node`` (8, FIGNet only): the same features along the surface-mesh edges.
- ``face_face`` (34, hyper-edges, both directions): between faces of different objects, not
  both static, within the collision radius (found with the broad phase; with
  `GraphConfig.speculative`, dynamic–static pairs out to the radius plus the step's
  displacement). Features: receiver
  closest point − sender closest point (3) and its norm, the sender's three vertices relative
  to its closest point (9) and their norms (3), the same for the receiver (12), the sender's
  and receiver's unit normals (6). Each triangle's vertices are ordered canonically — by
  distance to its closest point, ties broken by coordinates — and the hyper-edge's senders and
  receivers list the vertex nodes in that order, so nothing depends on a face's vertex order.
  With `GraphConfig.contact_velocity`, 4 more: the receiver's closest point's motion over the
  step minus the sender's (3; each interpolated from its face's vertices, which is exact for a
  rigid face) and its component along receiver − sender closest point (negative: closing).

Geometry is computed in float64 and only relative quantities are cast to float32.

Cost follows what moves and what touches: only the vertices that become nodes are moved to
world coordinates, and the broad phase reuses each static object's face bounds and k-d trees
while the object keeps its pose (`SceneGeometry.static_face_group`), so a static mesh of 100k
faces costs about what a 1k one does once it is cached (benchmarks/bench_static_scaling.py).
`SceneGraph.vertices` (every vertex) is still there but costs O(V); read
`SceneGraph.dynamic_vertex_positions` instead.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import torch

from fignetctl.core.broadphase import (
    FaceGroup,
    StaticFaceIndex,
    check_radius,
    face_pairs_between_groups,
    face_pairs_within_radius,
)
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
CONTACT_VELOCITY_FEATURE_SIZE = 4
INERTIA_FEATURE_SIZE = 9
CLOSED_TOLERANCE = 1e-3
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
    max_vertex_offset: float | None = 1.0
    """Face–face features hold each face's vertices relative to its closest point; vectors
    longer than this (metres) are shortened to it, keeping their direction. A floor of a few
    huge triangles then looks like any other face near the contact, instead of setting the
    normalizer's scale to tens of metres, and without the edges a subdivided floor costs.
    None: not clamped (model files older than this field read as None)."""
    static_receivers: bool = True
    """True: face–face edges run both ways between a dynamic and a static face. False: only
    into the dynamic face, so static nodes send but never aggregate: a floor vertex would
    otherwise sum the messages of every face near it, a scene-wide hub, and nothing a static
    node receives moves it. 28 % fewer face–face edges on movi-b. Model files before this
    field read as True."""
    speculative: bool = False
    """True: faces of a dynamic and a static object also pair within the radius plus the
    objects' largest vertex displacement over the step (dynamic: t−1 -> t; static: its given
    motion t -> t+1), at most the radius itself, so a fast object has a collision edge with
    the floor in the step before it reaches it, not only after. Without it, an object that
    covers the 0.2 m radius in one step reaches the floor with no edge. 2 × 0.2 m covers the
    99th percentile of floor impacts (0.32 m per frame). Pairs of two dynamic objects keep
    the radius: with the margin too they pair nearly all their faces while both fly fast
    (3.6× the face–face edges of 10 held-out trajectories on average, 47,758 at most)."""
    log_mass: bool = False
    """True: the mass feature is ln(mass / kg) (0 for static objects, whose mass is 0), so a
    mass ratio is a difference, whatever the masses; False: mass in kg (model files before
    this field)."""
    contact_velocity: bool = False
    """True: face–face edges also carry the relative motion of their two closest points over
    the step and its component along the line between them, the quantity an impact turns on,
    which the network would otherwise have to compose from six vertex nodes. False: the
    geometry alone (model files before this field)."""
    inertia: bool = False
    """True: object nodes also carry their inertia tensor per unit mass about the object node,
    in the world frame (I / m = R G R^T, 9 columns, m²; zeros on mesh nodes), which sets how an
    impulse changes the object's spin and which the network would otherwise have to assemble
    from its vertices' offsets. False: none (model files before this field)."""


# Where each feature block holds world-frame 3-vectors (the first column of each): a rotation
# of the whole scene rotates these and leaves every other column (norms, rest-shape vectors,
# materials, flags) as it is.
NODE_VECTOR_COLUMNS = (0, 3)  # velocity, kinematic displacement
NODE_TENSOR_COLUMNS = (NODE_FEATURE_SIZE,)  # the inertia tensor (GraphConfig.inertia), row-major
EDGE_VECTOR_COLUMNS = {
    MESH_TO_OBJECT: (0,),  # sender − receiver now; the rest-shape offset is in the object frame
    OBJECT_TO_MESH: (0,),
    NODE_NODE: (0,),
    # closest points, both triangles' vertex offsets, both normals, and the contact velocity
    FACE_FACE: (0, 4, 7, 10, 16, 19, 22, 28, 31, FACE_FACE_FEATURE_SIZE),
}


def rotated_graph(graph: MultiGraph, rotation: torch.Tensor) -> MultiGraph:
    """The graph of the same scene rotated by `rotation` (3, 3): its world-frame vectors rotated,
    connectivity and everything else kept. Equal to the graph built from the rotated poses,
    except that equidistant vertices of a face keep the order their unrotated coordinates gave
    them (`canonical_vertex_order`)."""
    edge_sets = {
        name: EdgeSet(
            name,
            _rotated_columns(edge_set.features, EDGE_VECTOR_COLUMNS[name], rotation),
            edge_set.senders,
            edge_set.receivers,
        )
        for name, edge_set in graph.edge_sets.items()
    }
    nodes = _rotated_columns(graph.node_features, NODE_VECTOR_COLUMNS, rotation, NODE_TENSOR_COLUMNS)
    return MultiGraph(nodes, edge_sets)


def _rotated_columns(features, starts, rotation, tensor_starts=()):
    """features with the 3-vectors that begin at `starts` rotated, and the row-major 3×3 tensors
    that begin at `tensor_starts` turned into R T R^T (each where the features are that wide)."""
    rotated = features.clone()
    rotation = rotation.to(features)
    for start in starts:
        if start + 3 <= features.shape[1]:
            rotated[:, start : start + 3] = features[:, start : start + 3] @ rotation.T
    for start in tensor_starts:
        if start + 9 <= features.shape[1]:
            tensors = features[:, start : start + 9].reshape(-1, 3, 3)
            rotated[:, start : start + 9] = (rotation @ tensors @ rotation.T).reshape(-1, 9)
    return rotated


def graph_signature_for(config: GraphConfig) -> GraphSignature:
    """The feature widths every graph built with `config` has."""
    sizes = {
        MESH_TO_OBJECT: RELATIVE_EDGE_FEATURE_SIZE,
        OBJECT_TO_MESH: RELATIVE_EDGE_FEATURE_SIZE,
        FACE_FACE: FACE_FACE_FEATURE_SIZE + CONTACT_VELOCITY_FEATURE_SIZE * config.contact_velocity,
    }
    if config.surface_edges:
        sizes[NODE_NODE] = RELATIVE_EDGE_FEATURE_SIZE
    node_size = NODE_FEATURE_SIZE + INERTIA_FEATURE_SIZE * config.inertia
    return GraphSignature(node_size, sizes, (FACE_FACE,))


@dataclasses.dataclass
class SceneGeometry:
    """The meshes of one scene, concatenated; fixed for a whole trajectory.

    rest_vertices : (V, 3) float64, each object's scaled mesh in its object frame
    vertex_object : (V,) int64, the object of each vertex
    faces : (F, 3) int64, global vertex indices, counter-clockwise seen from outside
    face_object : (F,) int64
    static : (O,) bool
    properties : (O, 3) float64, mass, friction, restitution

    Index arrays derived from these are computed once and kept (read-only), and
    `static_face_index` keeps each static object's broad-phase FaceGroup at its last pose, so
    a step costs nothing per face of static geometry that nothing comes near. The arrays
    above are therefore not to be modified after the first graph is built.
    """

    rest_vertices: np.ndarray
    vertex_object: np.ndarray
    faces: np.ndarray
    face_object: np.ndarray
    static: np.ndarray
    properties: np.ndarray
    static_face_index: StaticFaceIndex = dataclasses.field(
        default_factory=StaticFaceIndex, init=False, repr=False, compare=False
    )

    @property
    def num_objects(self) -> int:
        return int(self.static.shape[0])

    @functools.cached_property
    def dynamic_vertices(self) -> np.ndarray:
        """(Vd,) the global indices of the vertices of dynamic objects, in order."""
        return _read_only(np.flatnonzero(~self.static[self.vertex_object]))

    @functools.cached_property
    def object_vertices(self) -> list:
        """[(V_o,) int64 global vertex indices of object o, ascending] for each object."""
        return [_read_only(rows) for rows in _rows_of_each(self.vertex_object, self.num_objects)]

    @functools.cached_property
    def object_reach(self) -> np.ndarray:
        """(O,) float64 the distance of each object's farthest vertex from its centre."""
        reach = np.zeros(self.num_objects)
        np.maximum.at(reach, self.vertex_object, np.linalg.norm(self.rest_vertices, axis=1))
        return _read_only(reach)

    @functools.cached_property
    def inertia_per_mass(self) -> np.ndarray:
        """(O, 3, 3) float64 each object's inertia tensor per unit mass about its centre, in its
        object frame (`mesh_inertia_per_mass`; zeros for static objects)."""
        tensors = np.zeros((self.num_objects, 3, 3))
        for o in np.flatnonzero(~self.static):
            rows = self.object_vertices[o]
            faces = np.searchsorted(rows, self.faces[self.object_faces[o]])
            tensors[o] = mesh_inertia_per_mass(self.rest_vertices[rows], faces)
        return _read_only(tensors)

    @functools.cached_property
    def object_faces(self) -> list:
        """[(F_o,) int64 global face indices of object o, ascending] for each object."""
        return [_read_only(rows) for rows in _rows_of_each(self.face_object, self.num_objects)]

    @functools.cached_property
    def dynamic_face_corners(self) -> list:
        """[(F_o, 3) rows of `dynamic_vertices` of each face of object o] (dynamic objects; None
        for static ones)."""
        return [
            None if self.static[o] else _read_only(np.searchsorted(self.dynamic_vertices, self.faces[faces]))
            for o, faces in enumerate(self.object_faces)
        ]

    @functools.cached_property
    def surface_edges(self) -> np.ndarray:
        """(S, 2) int64 each undirected mesh edge once (global vertex indices, smaller first);
        made on first use (FIGNet's surface edges)."""
        return _read_only(unique_undirected_edges(self.faces))

    @functools.cached_property
    def surface_edges_by_lower_vertex(self):
        """(S,) order of `surface_edges` by their lower vertex, and those lower vertices sorted."""
        lower = self.surface_edges.min(axis=1) if len(self.surface_edges) else np.zeros(0, np.int64)
        order = np.argsort(lower, kind="stable")
        return _read_only(order), _read_only(lower[order])

    def world_vertices(self, positions, quaternions, vertices=None):
        """positions (O, 3), quaternions (O, 4) w x y z -> (V, 3) float64 world vertices, or
        (n, 3) those of the global vertex indices `vertices` (n,) (the same values as the
        rows of the full array)."""
        rows = slice(None) if vertices is None else np.asarray(vertices, np.int64)
        vertex_object = self.vertex_object[rows]
        rotations = quat_to_matrix(np.asarray(quaternions, np.float64))[vertex_object]
        rotated = np.einsum("vij,vj->vi", rotations, self.rest_vertices[rows])
        return rotated + np.asarray(positions, np.float64)[vertex_object]

    def static_face_group(self, object_index, positions, quaternions) -> FaceGroup:
        """The broad-phase FaceGroup of a static object at its pose in (O, 3), (O, 4); kept in
        `static_face_index` and rebuilt only when that object's pose changes."""
        key = _pose_key(positions, quaternions, object_index)
        return self.static_face_index.group(
            object_index, key, lambda: self._world_face_group(object_index, positions, quaternions)
        )

    def _world_face_group(self, object_index, positions, quaternions) -> FaceGroup:
        vertices = self.object_vertices[object_index]
        faces = self.object_faces[object_index]
        corners = np.searchsorted(vertices, self.faces[faces])
        return FaceGroup(faces, self.world_vertices(positions, quaternions, vertices), corners)

    def world_vertex_history(self, positions, quaternions):
        """(T, O, 3), (T, O, 4) -> (T, V, 3) world vertices of every frame; static objects at
        the pose of their kept FaceGroup are copied from it rather than transformed again."""
        history = np.empty((len(positions), len(self.rest_vertices), 3))
        for frame, (p, q) in enumerate(zip(positions, quaternions)):
            for o, vertices in enumerate(self.object_vertices):
                kept = self.static_face_index.kept(o, _pose_key(p, q, o)) if self.static[o] else None
                rows = _as_slice(vertices)
                history[frame, rows] = (
                    kept.vertices if kept is not None else self.world_vertices(p, q, vertices)
                )
        return history


def _read_only(array):
    array = np.asarray(array)
    array.flags.writeable = False
    return array


def _as_slice(rows):
    """Ascending unique indices as a slice where they are one contiguous run (cheaper to copy)."""
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return rows


def _rows_of_each(row_object, object_count):
    """[(n_o,) int64 rows whose object is o, ascending] for each object."""
    row_object = np.asarray(row_object, np.int64)
    order = np.argsort(row_object, kind="stable")
    boundaries = np.searchsorted(row_object[order], np.arange(object_count + 1))
    return [order[boundaries[k] : boundaries[k + 1]] for k in range(object_count)]


def _pose_key(positions, quaternions, object_index):
    """Bytes that identify one object's pose (exact float64 position and quaternion)."""
    position = np.asarray(positions, np.float64)[object_index]
    quaternion = np.asarray(quaternions, np.float64)[object_index]
    return position.tobytes() + quaternion.tobytes()


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
    )


def unique_undirected_edges(faces):
    """faces (F, 3) -> (S, 2) each mesh edge once, smaller index first."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    count = int(faces.max(initial=0)) + 1
    keys = np.unique(edges.min(axis=1) * count + edges.max(axis=1))  # sorted as (low, high)
    return np.stack([keys // count, keys % count], axis=1)


@dataclasses.dataclass
class SceneGraph:
    """A raw (unnormalized) graph and how its nodes map back to the scene.

    graph : MultiGraph with float32 features
    node_vertex : (N,) int64, the global vertex of each mesh node, −1 for object nodes
    num_dynamic_vertex_nodes : the first this many nodes are geometry.dynamic_vertices
    node_positions : (3, N, 3) float64 world positions of the nodes at t−1, t, t+1 (vertices
        for mesh nodes, centres of mass for object nodes)
    touching : (O,) bool, objects with a face in a collision pair (within the radius of
        another object's face, plus the speculative margins when the config has them)
    """

    graph: MultiGraph
    node_vertex: np.ndarray
    num_dynamic_vertex_nodes: int
    node_positions: np.ndarray
    geometry: SceneGeometry = dataclasses.field(repr=False)
    poses: tuple = dataclasses.field(repr=False)
    touching: np.ndarray = dataclasses.field(repr=False)

    @property
    def dynamic_vertex_positions(self) -> np.ndarray:
        """(3, Vd, 3) world positions of geometry.dynamic_vertices at t−1, t, t+1."""
        return self.node_positions[:, : self.num_dynamic_vertex_nodes]

    @functools.cached_property
    def vertices(self) -> np.ndarray:
        """(3, V, 3) float64 world vertices of frames t−1, t, t+1 it was built from.

        Costs O(V) (all static vertices too) on first use: read `dynamic_vertex_positions`
        where the dynamic vertices are all that is needed.
        """
        history = self.geometry.world_vertex_history(*self.poses)
        history[:, self.geometry.dynamic_vertices] = self.dynamic_vertex_positions
        return history


def build_scene_graph(geometry, positions, quaternions, config, velocities=None) -> SceneGraph:
    """Object poses at t−1, t, t+1 -> the raw graph of step t.

    positions : (3, O, 3) float, quaternions : (3, O, 4) float w x y z, for frames t−1, t, t+1;
    frame t+1 is read only for static objects (their given motion); pass anything finite
    (e.g. frame t) for the dynamic ones.
    velocities : None, or (linear (O, 3), angular (O, 3)) of the objects at t in metres and
    radians per step: the dynamic nodes' frame t−1 is then x_t − (v + ω × (x_t − c_t)), so
    that their velocity feature is their instantaneous velocity, and frame t−1 of dynamic
    objects is not read.

    Only dynamic vertices and the vertices of static faces in collision pairs are transformed
    to world coordinates; the broad phase reuses each static object's FaceGroup while its
    pose is unchanged (SceneGeometry.static_face_group).
    """
    positions = np.asarray(positions, np.float64)
    quaternions = np.asarray(quaternions, np.float64)
    dynamic_history = np.stack(
        [geometry.world_vertices(p, q, geometry.dynamic_vertices) for p, q in zip(positions, quaternions)]
    )
    if velocities is not None:
        positions, dynamic_history = _history_from_velocities(
            geometry, positions, dynamic_history, velocities
        )
    margins = (
        speculative_margins(geometry, dynamic_history, positions, quaternions, config.collision_radius)
        if config.speculative
        else None
    )
    pairs = collision_face_pairs_from_poses(
        geometry, dynamic_history[1], positions[1], quaternions[1], config.collision_radius, margins
    )
    node_vertex, node_object = select_nodes(geometry, pairs.face_i, pairs.face_j)
    node_history = node_position_history(
        geometry, node_vertex, node_object, dynamic_history, positions, quaternions
    )
    vertex_nodes = VertexNodes(node_vertex)
    edge_sets = object_mesh_edge_sets(geometry, node_vertex, node_object, node_history[1])
    edge_sets[FACE_FACE] = face_face_edge_set(
        geometry,
        node_history[1],
        pairs,
        vertex_nodes,
        config.max_vertex_offset,
        config.static_receivers,
        node_motion(geometry, node_object, node_history) if config.contact_velocity else None,
    )
    if config.surface_edges:
        edge_sets[NODE_NODE] = node_node_edge_set(geometry, node_history[1], vertex_nodes)
    node_features = node_feature_rows(geometry, node_vertex, node_object, node_history, config.log_mass)
    if config.inertia:
        inertia = world_inertia_rows(geometry, node_vertex, node_object, quaternions[1])
        node_features = np.concatenate([node_features, inertia], axis=1)
    graph = MultiGraph(torch.from_numpy(node_features), edge_sets)
    num_dynamic = len(geometry.dynamic_vertices)
    touching = np.zeros(len(geometry.static), bool)
    touching[geometry.face_object[np.concatenate([pairs.face_i, pairs.face_j])]] = True
    return SceneGraph(
        graph, node_vertex, num_dynamic, node_history, geometry, (positions, quaternions), touching
    )


def _history_from_velocities(geometry, positions, dynamic_history, velocities):
    """Frame t−1 of dynamic objects and vertices replaced by x_t − velocity (build_scene_graph)."""
    linear, angular = (np.asarray(v, np.float64) for v in velocities)
    dynamic = ~geometry.static
    positions = positions.copy()
    positions[0, dynamic] = positions[1, dynamic] - linear[dynamic]
    dynamic_history = dynamic_history.copy()
    dynamic_history[0] = dynamic_history[1] - rigid_point_velocities(
        dynamic_history[1], geometry.vertex_object[geometry.dynamic_vertices], positions[1], linear, angular
    )
    return positions, dynamic_history


def rigid_point_velocities(points, point_object, centres, linear, angular):
    """Velocities v + ω × (x − c) of points moving with their objects.

    points (P, 3), point_object (P,) the object of each point, centres (O, 3), linear and
    angular (O, 3) -> (P, 3) float64, in the units of linear
    """
    return linear[point_object] + np.cross(angular[point_object], points - centres[point_object])


def collision_face_pairs(geometry, vertices_now, radius):
    """(P,), (P,) face pairs of different objects, not both static, within `radius`.

    vertices_now : (V, 3) world vertices of every object (no cache: O(F) work).
    """
    triangles = np.asarray(vertices_now, np.float64)[geometry.faces]
    return face_pairs_within_radius(triangles, geometry.face_object, radius, geometry.static)


def speculative_margins(geometry, dynamic_history, positions, quaternions, cap):
    """(O,) each object's largest vertex displacement in metres, at most the collision
    radius (GraphConfig.speculative): dynamic objects over t−1 -> t (rows of
    `dynamic_history` (3, Vd, 3)), static ones over their given motion t -> t+1 (zero, and no
    work per vertex, while a static object stays put)."""
    margins = np.zeros(geometry.num_objects)
    if len(geometry.dynamic_vertices):
        displacement = np.linalg.norm(dynamic_history[1] - dynamic_history[0], axis=1)
        owner = geometry.vertex_object[geometry.dynamic_vertices]
        np.maximum.at(margins, owner, displacement)
    for o in np.flatnonzero(geometry.static):
        if _pose_key(positions[1], quaternions[1], o) != _pose_key(positions[2], quaternions[2], o):
            vertices = geometry.object_vertices[o]
            moved = geometry.world_vertices(positions[2], quaternions[2], vertices) - geometry.world_vertices(
                positions[1], quaternions[1], vertices
            )
            margins[o] = np.linalg.norm(moved, axis=1).max(initial=0.0)
    return np.minimum(margins, cap)


def collision_face_pairs_from_poses(
    geometry, dynamic_vertices_now, positions_now, quaternions_now, radius, margins=None
):
    """The pairs of `collision_face_pairs` (a broadphase.FacePairs, with their closest
    points), with static objects' faces taken from the kept FaceGroups of
    geometry.static_face_group: no work per static face that is not near a moving one (after
    the first call at a pose).

    dynamic_vertices_now : (Vd, 3) world positions of geometry.dynamic_vertices at t
    positions_now : (O, 3), quaternions_now : (O, 4), the poses at t
    margins : (O,) or None, added to the radius of pairs with a static object (`speculative_margins`)
    """
    radius = check_radius(radius)
    groups = []
    for o, faces in enumerate(geometry.object_faces):
        if geometry.static[o]:
            groups.append(geometry.static_face_group(o, positions_now, quaternions_now))
        else:
            groups.append(FaceGroup(faces, dynamic_vertices_now, geometry.dynamic_face_corners[o]))
    return face_pairs_between_groups(groups, geometry.static, radius, len(geometry.faces), margins)


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


def node_position_history(geometry, node_vertex, node_object, dynamic_history, positions, quaternions):
    """(3, N, 3) node positions at t−1, t, t+1: the dynamic vertices' (given, the first nodes),
    the static vertex nodes' (transformed here, only they) and the object centres."""
    num_dynamic = dynamic_history.shape[1]
    static_vertices = node_vertex[num_dynamic:][node_vertex[num_dynamic:] >= 0]
    history = np.asarray(positions, np.float64)[:, node_object]
    history[:, :num_dynamic] = dynamic_history
    for frame, (p, q) in enumerate(zip(positions, quaternions)):
        history[frame, num_dynamic : num_dynamic + len(static_vertices)] = geometry.world_vertices(
            p, q, static_vertices
        )
    return history


class VertexNodes:
    """Which node each global vertex is (mesh nodes only), without an array over all vertices.

    node_vertex : (N,) int64, −1 for object nodes
    """

    def __init__(self, node_vertex):
        mesh_nodes = np.flatnonzero(node_vertex >= 0)
        order = np.argsort(node_vertex[mesh_nodes], kind="stable")
        self.sorted_vertices = node_vertex[mesh_nodes][order]
        self.sorted_nodes = mesh_nodes[order]

    def contains(self, vertices):
        """(...) bool: True for vertices that are mesh nodes."""
        at = np.minimum(
            np.searchsorted(self.sorted_vertices, vertices), max(len(self.sorted_vertices) - 1, 0)
        )
        return (
            self.sorted_vertices[at] == vertices
            if len(self.sorted_vertices)
            else np.zeros(np.shape(vertices), bool)
        )

    def nodes(self, vertices):
        """(...) int64: the node of each vertex (all must be mesh nodes)."""
        return self.sorted_nodes[np.searchsorted(self.sorted_vertices, vertices)]


def node_motion(geometry, node_object, node_history):
    """(N, 3) each node's motion over the step as the graph knows it: a dynamic node's velocity
    (x_t − x_{t−1}, or its instantaneous velocity), a static node's given x_{t+1} − x_t."""
    static = geometry.static[node_object][:, None]
    return np.where(static, node_history[2] - node_history[1], node_history[1] - node_history[0])


def node_feature_rows(geometry, node_vertex, node_object, node_history, log_mass=False):
    """node_history (3, N, 3) positions at t−1, t, t+1 -> (N, 12) float32 node features;
    `log_mass`: the mass column is ln(mass) (0 where the mass is 0: static objects)."""
    static = geometry.static[node_object]
    properties = geometry.properties[node_object]
    if log_mass:
        mass = properties[:, 0]
        properties = np.column_stack([np.log(np.where(mass > 0, mass, 1.0)), properties[:, 1:]])
    velocity = node_history[1] - node_history[0]
    kinematic_displacement = (node_history[2] - node_history[1]) * static[:, None]
    is_object_node = node_vertex < 0
    columns = [
        velocity,
        kinematic_displacement,
        properties,
        static[:, None],
        (~is_object_node)[:, None],
        is_object_node[:, None],
    ]
    return np.concatenate(columns, axis=1).astype(np.float32)


def world_inertia_rows(geometry, node_vertex, node_object, quaternions):
    """(N, 9) float32: each object node's inertia per unit mass in the world frame, R G R^T with R
    its rotation at t (quaternions (O, 4)); zeros on mesh nodes."""
    rows = np.zeros((len(node_vertex), 9), np.float32)
    is_object_node = node_vertex < 0
    objects = node_object[is_object_node]
    rotations = quat_to_matrix(np.asarray(quaternions, np.float64)[objects])
    world = rotations @ geometry.inertia_per_mass[objects] @ np.swapaxes(rotations, 1, 2)
    rows[is_object_node] = world.reshape(-1, 9)
    return rows


def mesh_inertia_per_mass(vertices, faces) -> np.ndarray:
    """(3, 3) the inertia tensor per unit mass (m²) about the origin of a solid of uniform
    density bounded by the mesh: the signed tetrahedra from the origin to each face, whose
    second moments sum to the solid's (C = Σ v/20 (a aᵀ + b bᵀ + c cᵀ + s sᵀ), s = a + b + c,
    I = tr(C) 1 − C, divided by the volume Σ v; both change sign with the winding). Where the
    mesh is not closed (its faces' area vectors do not sum to under CLOSED_TOLERANCE of their
    lengths' sum) or encloses no volume, the vertices as equal point masses."""
    vertices = np.asarray(vertices, np.float64)
    corners = vertices[np.asarray(faces, np.int64)]
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    volumes = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    volume = volumes.sum()
    areas = np.cross(b - a, c - a)  # a closed surface's sum to zero: its volume is the same from any origin
    closed = np.linalg.norm(areas.sum(axis=0)) <= CLOSED_TOLERANCE * np.linalg.norm(areas, axis=1).sum()
    if closed and np.isfinite(volume) and abs(volume) > 0:  # either winding
        s = a + b + c
        outer = sum(np.einsum("fi,fj->fij", x, x) for x in (a, b, c, s))
        second_moment = np.einsum("f,fij->ij", volumes / 20.0, outer) / volume
    else:
        second_moment = vertices.T @ vertices / max(len(vertices), 1)
    return np.trace(second_moment) * np.eye(3) - second_moment


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


def node_node_edge_set(geometry, node_now, vertex_nodes):
    """FIGNet's surface-mesh edges, both directions, between mesh nodes in the graph."""
    edges = geometry.surface_edges[surface_edges_between(geometry, vertex_nodes)]
    edges = np.concatenate([edges, edges[:, ::-1]])
    senders, receivers = vertex_nodes.nodes(edges[:, 0]), vertex_nodes.nodes(edges[:, 1])
    features = relative_edge_features(
        node_now[senders],
        node_now[receivers],
        geometry.rest_vertices[edges[:, 0]],
        geometry.rest_vertices[edges[:, 1]],
    )
    return _edge_set(NODE_NODE, features, senders, receivers)


def surface_edges_between(geometry, vertex_nodes):
    """(E,) ascending indices of the surface edges whose two ends are both mesh nodes, found
    from the edges of each node's vertex (no pass over all edges)."""
    order, lower = geometry.surface_edges_by_lower_vertex
    starts = np.searchsorted(lower, vertex_nodes.sorted_vertices, side="left")
    ends = np.searchsorted(lower, vertex_nodes.sorted_vertices, side="right")
    counts = ends - starts
    offsets = np.repeat(starts - np.cumsum(counts) + counts, counts)
    candidates = order[np.arange(counts.sum()) + offsets]
    both = vertex_nodes.contains(geometry.surface_edges[candidates]).all(axis=1)
    return np.sort(candidates[both])


def face_face_edge_set(
    geometry, node_now, pairs, vertex_nodes, max_vertex_offset=None, static_receivers=True, motion=None
):
    """Collision hyper-edges for the face pairs (a broadphase.FacePairs), in both directions
    (into dynamic faces only unless `static_receivers`), from the pairs' closest points;
    `motion` (N, 3) per node (node_motion): the contact-velocity columns too."""
    sender_faces = np.concatenate([pairs.face_i, pairs.face_j])
    receiver_faces = np.concatenate([pairs.face_j, pairs.face_i])
    sender_points = np.concatenate([pairs.point_i, pairs.point_j])
    receiver_points = np.concatenate([pairs.point_j, pairs.point_i])
    distance = np.concatenate([pairs.distance, pairs.distance])
    if not static_receivers:
        into_dynamic = ~geometry.static[geometry.face_object[receiver_faces]]
        sender_faces, receiver_faces = sender_faces[into_dynamic], receiver_faces[into_dynamic]
        sender_points, receiver_points = sender_points[into_dynamic], receiver_points[into_dynamic]
        distance = distance[into_dynamic]
    sender_nodes = vertex_nodes.nodes(geometry.faces[sender_faces])
    receiver_nodes = vertex_nodes.nodes(geometry.faces[receiver_faces])
    features, sender_order, receiver_order = face_face_features(
        node_now[sender_nodes],
        node_now[receiver_nodes],
        max_vertex_offset,
        (sender_points, receiver_points, distance),
        None if motion is None else (motion[sender_nodes], motion[receiver_nodes]),
    )
    senders = np.take_along_axis(sender_nodes, sender_order, axis=1)
    receivers = np.take_along_axis(receiver_nodes, receiver_order, axis=1)
    return _edge_set(FACE_FACE, features, senders, receivers)


def face_face_features(
    sender_triangles, receiver_triangles, max_vertex_offset=None, closest=None, motion=None
):
    """(E, 3, 3) x2 -> features (E, 34 or 38) float32, sender_order (E, 3), receiver_order (E, 3).

    The orders give each triangle's vertices canonically (see the module docstring); vertex
    offsets from the closest point are clamped to `max_vertex_offset` in length (None: not).
    closest : (sender point (E, 3), receiver point (E, 3), distance (E,)) when already known
    (the broad phase computes them), else None: computed here.
    motion : None, or (sender (E, 3, 3), receiver (E, 3, 3)) each vertex's motion over the step,
    in the triangles' vertex order: 4 contact-velocity columns are appended (E, 38).
    """
    sender_point, receiver_point, distance = (
        closest_points_triangles(sender_triangles, receiver_triangles) if closest is None else closest
    )
    sender_order = canonical_vertex_order(sender_triangles, sender_point)
    receiver_order = canonical_vertex_order(receiver_triangles, receiver_point)
    sender_relative = _clamped(
        _ordered(sender_triangles, sender_order) - sender_point[:, None], max_vertex_offset
    )
    receiver_relative = _clamped(
        _ordered(receiver_triangles, receiver_order) - receiver_point[:, None], max_vertex_offset
    )
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
    if motion is not None:
        closing = point_motion(receiver_triangles, receiver_point, motion[1]) - point_motion(
            sender_triangles, sender_point, motion[0]
        )
        direction = np.divide(
            receiver_point - sender_point,
            distance[:, None],
            out=np.zeros_like(closing),
            where=distance[:, None] > 0,
        )
        columns += [closing, np.sum(closing * direction, axis=1, keepdims=True)]
    features = np.concatenate(columns, axis=1).astype(np.float32)
    return features, sender_order, receiver_order


def point_motion(triangles, points, vertex_motion):
    """(E, 3, 3) triangles, (E, 3) points on them, (E, 3, 3) their vertices' motion -> (E, 3)
    each point's motion, interpolated barycentrically (exact for a rigid or affine motion); a
    degenerate triangle gives its nearest vertex's."""
    return np.einsum("ek,ekd->ed", barycentric_weights(triangles, points), vertex_motion)


def barycentric_weights(triangles, points):
    """(E, 3, 3) triangles, (E, 3) points on them -> (E, 3) barycentric coordinates (clipped to
    the triangle; a degenerate triangle's nearest vertex gets all the weight)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2, p = b - a, c - a, points - a
    d11, d12, d22 = (np.sum(u * v, axis=1) for u, v in ((e1, e1), (e1, e2), (e2, e2)))
    dp1, dp2 = np.sum(p * e1, axis=1), np.sum(p * e2, axis=1)
    denominator = d11 * d22 - d12 * d12
    regular = denominator > 1e-12 * np.maximum(d11 * d22, 1e-300)
    safe = np.where(regular, denominator, 1.0)
    v = (d22 * dp1 - d12 * dp2) / safe
    w = (d11 * dp2 - d12 * dp1) / safe
    weights = np.clip(np.stack([1.0 - v - w, v, w], axis=1), 0.0, None)
    weights /= np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
    nearest = np.argmin(np.linalg.norm(triangles - points[:, None], axis=2), axis=1)
    weights[~regular] = np.eye(3)[nearest[~regular]]
    return weights


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


def _clamped(vectors, max_length):
    """(..., 3) vectors shortened to at most `max_length`, directions kept (None: unchanged)."""
    if max_length is None:
        return vectors
    lengths = np.linalg.norm(vectors, axis=-1, keepdims=True)
    return vectors * np.minimum(1.0, max_length / np.maximum(lengths, 1e-300))


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
