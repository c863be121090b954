"""The learned simulator around the network: features in, rigid poses out.

Three layers, as in learning_to_simulate: `EncodeProcessDecode` (network.py) sees only
normalized graphs; `LearnedSimulator` here builds and normalizes graphs (`preprocess`), turns
the network's normalized accelerations into next positions (`postprocess`), and makes training
targets (`inverse_postprocess`); noise comes from noise.py and is passed in.

One step reads like the paper:

    scene_graph = build_scene_graph(geometry, positions, quaternions, config.graph, velocities)
    normalized_acceleration = self.network(self.preprocess(scene_graph.graph))
    next_vertices, next_vertex_velocities = self.postprocess(normalized_acceleration, vertices_previous, vertices_now)
    next_pose = shape_match(rest shape -> next_vertices)   # rigid, never a reflection

Two kinds of state (`SimulatorConfig.state`):

- ``"positions"`` (FIGNet): frames t−1 and t; a vertex's velocity is x_t − x_{t−1}, the decoder
  gives one acceleration a per vertex and x_{t+1} = x_t + (x_t − x_{t−1}) + a. At 30 fps a frame
  holds 8 physics steps, so after an impact inside the frame x_t − x_{t−1} mixes the velocities
  before and after it: two frames do not determine the next one.
- ``"velocities"``: frame t and each object's instantaneous linear and angular velocity, a
  state that does. A vertex's velocity feature is u_t = (v + ω × (x − c)) · dt (metres per
  frame, as x_t − x_{t−1} was); the decoder gives two vectors per vertex, a_x and a_u, and

      x_{t+1} = x_t + u_t + a_x          u_{t+1} = u_t + a_u

  The next pose is shape-matched to x_{t+1}, the next (v, ω) is the rigid velocity field
  fitted to u_{t+1} by least squares (`rigid_velocities_from_vertices`).

With `SimulatorConfig.free_motion` (velocity state only) the decoder gives what contact changes
of free motion instead: a_x and a_u are each vertex's free-motion corrections (the object's
centre on its parabola under gravity, its spin constant: `free_motion_corrections`) plus the
network's output, so an object that touches nothing needs the answer 0 from the network, and
gravity and the turn of a spinning object are computed, not learned.
"""

from __future__ import annotations

import dataclasses
import json
import numbers

import numpy as np
import torch
from torch import nn

from fignetctl.core.model.graph import EdgeSet, MultiGraph, batch_graphs
from fignetctl.core.model.network import PRESETS as NETWORK_PRESETS
from fignetctl.core.model.network import EncodeProcessDecode, NetworkConfig
from fignetctl.core.model.normalizer import Normalizer
from fignetctl.core.model.scene_data import DECIMATIONS
from fignetctl.core.model.scene_graph import (
    GraphConfig,
    build_scene_graph,
    graph_signature_for,
    rotated_graph,
)
from fignetctl.core.shape_matching import fit_rigid_transform
from fignetctl.core.transforms import (
    matrix_to_quat,
    quat_conjugate,
    quat_from_axis_angle,
    quat_from_rotation_vector,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
)
from fignetctl.errors import FignetError

STATES = ("positions", "velocities")

# Floor of every normalizer's std: features are in metres (per step) and material units, so a
# spread below a micrometre is float rounding, which must not be blown up into signal.
STD_EPSILON = 1e-6
MAX_ROTATIONS = 64
"""The most turns about gravity the network may be averaged over (`network_acceleration`)."""


@dataclasses.dataclass(frozen=True)
class SimulatorConfig:
    """Everything that defines a learned simulator's inputs and network."""

    network: NetworkConfig = NETWORK_PRESETS["small"]
    """Sizes of the encode–process–decode network."""
    graph: GraphConfig = GraphConfig()
    """Collision radius and FIGNet (surface edges) or FIGNet* (none)."""
    max_faces_per_object: int | None = 256
    """Dynamic objects' meshes are decimated (`decimation`) to at most this many faces; None
    keeps them. Static meshes are kept whole (scene_data.py)."""
    decimation: str = "closest"
    """How (scene_data.decimated_mesh): 'closest', quadric decimation unless it moves the
    surface by more than 1 % of the object's size, then the nearer of it and the decimated
    surface-preserving reduction; 'quadric' (model files before this field), quadric
    decimation alone, which moved the movi-b mug's surface by a third of its size."""
    max_static_edge: float | None = None
    """Static meshes are subdivided until no edge is longer than this (m); None keeps them.
    The face–face features hold each face's vertices relative to its closest point, so one
    80 m floor triangle beside 0.1 m object triangles would set the normalizer's scale to
    tens of metres and hide the object's contact geometry. Subdividing the floor to 1 m (the
    v2 retraining) fixed that at 2.8x the face-face edges; clamping the offsets
    (`GraphConfig.max_vertex_offset`, the default now) fixes it with none."""
    state: str = "positions"
    """'positions' (frames t−1 and t) or 'velocities' (frame t and instantaneous velocities);
    module docstring."""
    dt: float | None = None
    """Seconds per step of the training data (None: not recorded, model files before it)."""
    gravity: tuple | None = None
    """Gravity (m/s²) of the training data (None: not recorded)."""
    free_motion: bool = False
    """True (velocity state only): the network decodes the change contact makes to free motion,
    which is added to it (module docstring); False: the whole correction (model files before
    this field)."""

    def __post_init__(self) -> None:
        if self.free_motion and self.state != "velocities":
            raise ValueError("free_motion needs the velocity state (state='velocities')")
        if self.state not in STATES:
            raise ValueError(f"state must be one of {STATES}, not {self.state!r}")
        if self.decimation not in DECIMATIONS:
            raise ValueError(f"decimation must be one of {DECIMATIONS}, not {self.decimation!r}")
        if self.network.output_size != output_size_for(self.state):
            raise ValueError(
                f"a {self.state!r} model decodes {output_size_for(self.state)} numbers per node, "
                f"the network {self.network.output_size}"
            )

    @property
    def uses_velocities(self) -> bool:
        return self.state == "velocities"

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> SimulatorConfig:
        values = json.loads(text)
        graph = {
            "max_vertex_offset": None,
            "static_receivers": True,
            **values["graph"],
        }  # absent: a model file older than the field
        gravity = values.get("gravity")
        return cls(
            network=NetworkConfig(**values["network"]),
            graph=GraphConfig(**graph),
            max_faces_per_object=values["max_faces_per_object"],
            decimation=values.get("decimation", "quadric"),  # absent: decimated so in training
            max_static_edge=values.get("max_static_edge"),  # absent: a model trained without
            state=values.get("state", "positions"),
            dt=values.get("dt"),
            gravity=None if gravity is None else tuple(gravity),
            free_motion=values.get("free_motion", False),  # absent: a model file older than the field
        )


def output_size_for(state: str) -> int:
    """Numbers decoded per node: a_x (positions), or a_x and a_u (velocities)."""
    return 6 if state == "velocities" else 3


class LearnedSimulator(nn.Module):
    """Normalizers and the network; predicts the next world vertices of dynamic objects."""

    def __init__(self, config: SimulatorConfig):
        super().__init__()
        self.config = config
        signature = graph_signature_for(config.graph)
        self.network = EncodeProcessDecode(config.network, signature)
        self.node_normalizer = Normalizer(signature.node_feature_size, std_epsilon=STD_EPSILON)
        self.edge_normalizers = nn.ModuleDict(
            {
                name: Normalizer(size, std_epsilon=STD_EPSILON)
                for name, size in signature.edge_feature_sizes.items()
            }
        )
        self.acceleration_normalizer = Normalizer(config.network.output_size, std_epsilon=STD_EPSILON)
        self.source_sha256 = None  # the SHA-256 of the model file it was loaded from, if any
        self.trained_properties = None  # ranges of the training data's properties (trained_ranges.py)
        self.rotations = 1  # predictions averaged over this many turns about gravity (network_acceleration)

    def with_graph_config(self, **changes) -> LearnedSimulator:
        """A copy with the same weights and normalizers, on the same device and in the same mode,
        that builds its graphs with these GraphConfig fields changed (collision_radius, say), for
        sweeps over graph settings. Changes that would reshape the network are refused."""
        config = dataclasses.replace(self.config, graph=dataclasses.replace(self.config.graph, **changes))
        other = LearnedSimulator(config)
        try:
            other.load_state_dict(self.state_dict())
        except RuntimeError:
            raise FignetError(
                f"graph settings {changes} change the network's inputs; train a model for them"
            ) from None
        other.trained_properties, other.source_sha256 = self.trained_properties, self.source_sha256
        other.rotations = self.rotations
        return other.to(next(self.parameters()).device).train(self.training)

    def preprocess(self, graph: MultiGraph, accumulate: bool) -> MultiGraph:
        """Raw graph -> normalized graph (statistics updated when `accumulate`)."""
        nodes = self.node_normalizer(graph.node_features, accumulate)
        edge_sets = {
            name: self._normalized_edge_set(edge_set, accumulate)
            for name, edge_set in graph.edge_sets.items()
        }
        return MultiGraph(nodes, edge_sets)

    def _normalized_edge_set(self, edge_set: EdgeSet, accumulate: bool) -> EdgeSet:
        normalizer = self.edge_normalizers[edge_set.name]
        accumulate = accumulate and edge_set.num_edges > 0
        if normalizer.count.item() == 0 and not accumulate:
            return edge_set  # an edge type never seen in training: no statistics to apply
        features = normalizer(edge_set.features, accumulate)
        return EdgeSet(edge_set.name, features, edge_set.senders, edge_set.receivers)

    def forward(self, graph: MultiGraph, accumulate: bool = False) -> torch.Tensor:
        """Raw graph -> (N, 3) normalized per-node accelerations."""
        return self.network(self.preprocess(graph, accumulate))

    def inverse_postprocess(
        self,
        next_vertices,
        vertices_previous,
        vertices_now,
        next_vertex_velocities=None,
        accumulate=False,
        free_motion=None,
    ):
        """What the network must output to reach x_{t+1} (and u_{t+1} for a velocity state) from
        the history: normalized `acceleration_targets`, less `free_motion` ((n, 6), a
        free-motion model's `free_motion_of`) when given, a (n, output_size) float32 tensor."""
        targets = acceleration_targets(
            next_vertices, vertices_previous, vertices_now, next_vertex_velocities, free_motion
        )
        return self.normalized_targets(torch.from_numpy(targets.astype(np.float32)), accumulate)

    def network_acceleration(self, graph: MultiGraph) -> torch.Tensor:
        """Raw graph -> (N, output_size) accelerations, denormalized.

        With `rotations` = K > 1, the network is run on the scene turned by 2πk/K (k < K) about
        the gravity axis, each answer turned back, and the K answers averaged: physics does not
        change when a scene turns about gravity, and the average is exactly equivariant to those
        K turns, where the network alone is only as equivariant as its training made it. Costs
        K network evaluations (one batch) per step; the graph is built once.
        """
        if not whole_turns(self.rotations):
            raise FignetError(
                f"rotations must be a whole number of turns from 1 to {MAX_ROTATIONS}, not {self.rotations!r}"
            )
        if self.rotations == 1:
            return self.acceleration_normalizer.inverse(self(graph))
        turns = rotations_about_gravity(self.rotations, self.config.gravity).to(graph.node_features)
        answers = self.acceleration_normalizer.inverse(
            self(batch_graphs([rotated_graph(graph, turn) for turn in turns]))
        )
        answers = answers.reshape(len(turns), graph.num_nodes, -1, 3)
        turned_back = torch.einsum("kij,knvi->knvj", turns, answers)  # R_kᵀ a for each vector a
        return turned_back.mean(0).reshape(graph.num_nodes, -1)

    def normalized_targets(self, targets: torch.Tensor, accumulate: bool) -> torch.Tensor:
        """(n, output_size) raw `acceleration_targets` -> normalized (statistics updated when `accumulate`)."""
        return self.acceleration_normalizer(targets, accumulate)

    def postprocess(self, normalized_acceleration, vertices_previous, vertices_now, free_motion=None):
        """The network's output -> x_{t+1}, and u_{t+1} for a velocity state (None for a
        positions state): `integrate` of the denormalized output plus `free_motion` (as in
        `inverse_postprocess`) when given; float64 numpy."""
        acceleration = self.acceleration_normalizer.inverse(normalized_acceleration)
        acceleration = acceleration.detach().cpu().double().numpy()
        return integrate(acceleration, vertices_previous, vertices_now, free_motion)

    def step_velocities(self, positions, quaternions, velocities):
        """(O, 3) x2 linear and angular velocities in metres and radians per step at frame t:
        the given ones (m/s, rad/s) times dt, or, when None, estimated from frames t−1 and t."""
        if velocities is None:
            return finite_difference_step_velocities(positions[:2], quaternions[:2])
        if self.config.dt is None:
            raise FignetError("the model file records no time step, so velocities cannot be given to it")
        return tuple(np.asarray(v, np.float64) * self.config.dt for v in velocities)

    @torch.no_grad()
    def step(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        """Predict the poses of frame t+1: `predict`'s positions (O, 3) and quaternions (O, 4)."""
        return self.predict(geometry, positions, quaternions, free_flight, velocities)[:2]

    @torch.no_grad()
    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        """Predict frame t+1.

        positions (3, O, 3), quaternions (3, O, 4): frames t−1, t, t+1; frame t+1 is read for
            static objects only; frame t−1 of dynamic objects only by a positions-state model,
            or to estimate velocities that are not given.
        velocities : None, or (linear (O, 3) m/s, angular (O, 3) rad/s) at frame t, read by a
            velocities-state model.
        free_flight : None, or gravity · dt² (3,) in metres per step²: a dynamic object with no
            face within the collision radius of another object's face has no edge to anything
            outside itself, so physics leaves one answer for it, free flight, which is then
            used instead of the network's; when no object touches anything the network is
            not run.

        Returns next positions (O, 3), quaternions (O, 4), and for a velocities-state model the
        next linear and angular velocities (O, 3) in m/s and rad/s (None, None otherwise), all
        float64, with static objects' poses taken from frame t+1.
        """
        step_velocities = (
            self.step_velocities(positions, quaternions, velocities) if self.config.uses_velocities else None
        )
        scene_graph = build_scene_graph(geometry, positions, quaternions, self.config.graph, step_velocities)
        flying = np.zeros(geometry.num_objects, bool)
        if free_flight is not None:
            flying = ~geometry.static & ~scene_graph.touching
        if free_flight is not None and np.array_equal(flying, ~geometry.static):  # nothing touches anything
            predicted = self._standing_still(positions[2], quaternions[2])
        else:
            free_motion = free_motion_of(
                self.config, geometry, scene_graph.dynamic_vertex_positions[1], positions[1], step_velocities
            )
            predicted = self._network_prediction(
                geometry, scene_graph, positions[2], quaternions[2], free_motion
            )
        if flying.any():
            flown = self._free_flight(positions, quaternions, step_velocities, free_flight)
            for values, flown_values in zip(predicted, flown):
                if values is not None:
                    values[flying] = flown_values[flying]
        return self._physical(predicted)

    def _network_prediction(
        self, geometry, scene_graph, static_positions, static_quaternions, free_motion=None
    ):
        """[positions, quaternions, linear, angular] at t+1 (velocities per step, or None);
        `free_motion`: what the network's output is added to (`free_motion_of`), or None."""
        device = next(self.parameters()).device
        acceleration = self.network_acceleration(scene_graph.graph.to(device))
        acceleration = acceleration[: scene_graph.num_dynamic_vertex_nodes].detach().cpu().double().numpy()
        next_vertices, next_vertex_velocities = integrate(
            acceleration, *scene_graph.dynamic_vertex_positions[:2], free_motion
        )
        positions, quaternions = rigid_poses_from_vertices(
            geometry, next_vertices, static_positions, static_quaternions
        )
        if not self.config.uses_velocities:
            return [positions, quaternions, None, None]
        return [
            positions,
            quaternions,
            *rigid_velocities_from_vertices(geometry, next_vertices, next_vertex_velocities, positions),
        ]

    def _standing_still(self, positions, quaternions):
        """The same list as `_network_prediction` for objects kept at the given poses."""
        state = [np.array(positions, np.float64), np.array(quaternions, np.float64)]
        return state + (
            [np.zeros_like(state[0]), np.zeros_like(state[0])]
            if self.config.uses_velocities
            else [None, None]
        )

    def _free_flight(self, positions, quaternions, step_velocities, gravity_step):
        if step_velocities is None:
            return (*free_flight_poses(positions[:2], quaternions[:2], gravity_step), None, None)
        return free_flight_state(positions[1], quaternions[1], *step_velocities, gravity_step)

    def _physical(self, state):
        """Velocities per step -> m/s and rad/s (a tuple of four; None, None for a positions state)."""
        positions, quaternions, linear, angular = state
        if linear is None:
            return positions, quaternions, None, None
        return positions, quaternions, linear / self.config.dt, angular / self.config.dt


def whole_turns(value) -> bool:
    """True for a number of turns the network may be averaged over: a whole number from 1 to
    MAX_ROTATIONS (numpy's integers too, not bools)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and 1 <= value <= MAX_ROTATIONS


def rotations_about_gravity(count, gravity=None) -> torch.Tensor:
    """(count, 3, 3) float32 rotations by 2πk/count, k = 0 … count−1, about the axis of
    `gravity` (3,), or about z when it is None or zero (the up axis of every dataset here)."""
    up = (0.0, 0.0, 1.0) if gravity is None or not np.any(gravity) else -np.asarray(gravity, np.float64)
    angles = 2 * np.pi * np.arange(count) / count
    turns = quat_to_matrix(quat_from_axis_angle(np.broadcast_to(up, (count, 3)), angles))
    return torch.from_numpy(turns.astype(np.float32))


def acceleration_targets(
    next_vertices, vertices_previous, vertices_now, next_vertex_velocities=None, free_motion=None
):
    """The raw targets that `integrate` (given the same `free_motion`) turns back into x_{t+1}
    (and u_{t+1}).

    All (n, 3); the vertex velocity is u_t = x_t − x_{t−1} (module docstring).
    returns (n, 3) a_x = x_{t+1} − x_t − u_t, or (n, 6) [a_x, a_u = u_{t+1} − u_t] when
    next_vertex_velocities is given, less `free_motion` ((n, 6) `free_motion_of`) when given;
    float64
    """
    velocity = np.asarray(vertices_now, np.float64) - vertices_previous
    targets = np.asarray(next_vertices, np.float64) - vertices_now - velocity
    if next_vertex_velocities is not None:
        targets = np.concatenate([targets, np.asarray(next_vertex_velocities, np.float64) - velocity], axis=1)
    return targets if free_motion is None else targets - free_motion


def free_motion_of(config, geometry, vertices_now, centres, step_velocities) -> np.ndarray | None:
    """(Vd, 6) `free_motion_corrections` of the dynamic vertices when `config` (a
    SimulatorConfig) has `free_motion`: what the network's output is added to; else None.

    vertices_now : (Vd, 3) geometry.dynamic_vertices at t; centres : (O, 3) the objects' centres
    at t; step_velocities : (linear, angular) (O, 3) each, per step (the angular one is read)."""
    if not config.free_motion:
        return None
    if config.dt is None or config.gravity is None:
        raise FignetError("a free-motion model must record the time step and gravity of its data")
    gravity_step = np.asarray(config.gravity, np.float64) * config.dt**2
    owner = geometry.vertex_object[geometry.dynamic_vertices]
    return free_motion_corrections(vertices_now, owner, centres, step_velocities[1], gravity_step)


def free_motion_corrections(vertices, vertex_object, centres, angular, gravity_step) -> np.ndarray:
    """(n, 6) [a_x, a_u] of vertices over one step of their objects' free motion: each centre on
    its parabola, each spin constant (as `free_flight_state`).

    For a vertex at offset r = x − c from its object's centre, with linear velocity v and angular
    velocity ω (per step), u = v + ω × r, a_g = gravity · dt² and R the turn by ω:
        a_x = x' − x − u = a_g / 2 + R r − r − ω × r
        a_u = u' − u     = a_g + ω × (R r − r)
    The centre's own velocity v cancels from both: u carries it. vertices (n, 3) at t,
    vertex_object (n,) the object of each; centres, angular (O, 3) at t (radians per step);
    gravity_step (3,) metres per step². float64
    """
    angular = np.asarray(angular, np.float64)
    turns = quat_to_matrix(quat_from_rotation_vector(angular))  # one per object
    offsets = np.asarray(vertices, np.float64) - np.asarray(centres, np.float64)[vertex_object]
    turned = np.einsum("nij,nj->ni", turns[vertex_object], offsets)
    angular = angular[vertex_object]
    gravity_step = np.asarray(gravity_step, np.float64)
    position = 0.5 * gravity_step + turned - offsets - np.cross(angular, offsets)
    velocity = gravity_step + np.cross(angular, turned - offsets)
    return np.concatenate([position, velocity], axis=1)


def integrate(acceleration, vertices_previous, vertices_now, free_motion=None):
    """x_{t+1} = x_t + u_t + a_x, and u_{t+1} = u_t + a_u when the acceleration has 6 columns,
    with `free_motion` ((n, 6) `free_motion_of`) added to the acceleration when given.

    acceleration : (n, 3) or (n, 6); vertices : (n, 3). Returns x_{t+1} and u_{t+1} or None.
    """
    if free_motion is not None:
        acceleration = acceleration + free_motion
    velocity = np.asarray(vertices_now, np.float64) - vertices_previous
    next_vertices = vertices_now + velocity + acceleration[:, :3]
    if acceleration.shape[1] == 3:
        return next_vertices, None
    return next_vertices, velocity + acceleration[:, 3:]


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


def finite_difference_step_velocities(positions, quaternions):
    """(2, O, 3), (2, O, 4) frames t−1, t -> linear (O, 3) metres per step and angular (O, 3)
    radians per step: x_t − x_{t−1} and the rotation vector of q_t ⊗ q_{t−1}⁻¹."""
    from fignetctl.core.transforms import quat_to_rotation_vector

    positions = np.asarray(positions, np.float64)
    quaternions = np.asarray(quaternions, np.float64)
    turn = quat_multiply(quaternions[1], quat_conjugate(quaternions[0]))
    return positions[1] - positions[0], quat_to_rotation_vector(turn)


def free_flight_state(positions, quaternions, linear, angular, acceleration):
    """The state at t+1 of rigid bodies in free flight, from their state at t: the centre on
    its parabola, the spin constant (as `free_flight_poses`).

    positions (O, 3), quaternions (O, 4) at t; linear (O, 3) metres per step, angular (O, 3)
    radians per step; acceleration (3,) metres per step² (gravity · dt²)
    returns positions, quaternions, linear, angular at t+1 (per step), float64
    """
    acceleration = np.asarray(acceleration, np.float64)
    linear = np.asarray(linear, np.float64)
    angular = np.asarray(angular, np.float64)
    next_positions = np.asarray(positions, np.float64) + linear + 0.5 * acceleration
    next_quaternions = quat_normalize(quat_multiply(quat_from_rotation_vector(angular), quaternions))
    return next_positions, next_quaternions, linear + acceleration, angular.copy()


def rigid_velocities_from_vertices(geometry, dynamic_vertex_positions, dynamic_vertex_velocities, centres):
    """The rigid velocity field closest to each dynamic object's predicted vertex velocities.

    For object o with centre c and vertices x_i moving at u_i, (v, ω) minimises
    Σ_i |v + ω × (x_i − c) − u_i|² (a 6 × 6 linear least-squares problem per object).

    dynamic_vertex_positions, dynamic_vertex_velocities : (Vd, 3), rows of geometry.dynamic_vertices
    centres : (O, 3) the objects' centres at the same time
    returns linear (O, 3), angular (O, 3) float64 in the units of the velocities (zero for static objects)
    """
    linear = np.zeros((geometry.num_objects, 3))
    angular = np.zeros((geometry.num_objects, 3))
    owner = geometry.vertex_object[geometry.dynamic_vertices]
    for obj in np.flatnonzero(~geometry.static):
        rows = owner == obj
        offsets = dynamic_vertex_positions[rows] - centres[obj]
        design = np.zeros((len(offsets), 3, 6))
        design[:, :, :3] = np.eye(3)
        design[:, :, 3:] = -_cross_matrices(offsets)  # ω × r = −[r]× ω
        solution, *_ = np.linalg.lstsq(
            design.reshape(-1, 6), dynamic_vertex_velocities[rows].reshape(-1), rcond=None
        )
        linear[obj], angular[obj] = solution[:3], solution[3:]
    return linear, angular


def _cross_matrices(vectors):
    """(n, 3) -> (n, 3, 3) [r]×, the matrices with [r]× · w = r × w."""
    x, y, z = np.asarray(vectors, np.float64).T
    zero = np.zeros_like(x)
    return np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(-1, 3, 3)


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
        rotation, translation = fit_rigid_transform(
            geometry.rest_vertices[dynamic[rows]], dynamic_vertex_positions[rows]
        )
        positions[obj] = translation
        quaternions[obj] = matrix_to_quat(rotation)
    return positions, quaternions
