"""A loss through several steps of the simulator (`TrainingSettings.unroll` = n ≥ 2).

The one-step loss asks for frame t+1 from the recording's frame t. A rollout then starts
each step from its own last answer, and an error in the velocity it gave moves every later
frame. With n steps, the network's answer for t+1 becomes the state of a second step whose
answer for t+2 is scored too, that answer the state of a third, and so on to t+n; the
gradient of each later score reaches every earlier answer through the states they made.

Graph building is numpy and not differentiable, so step k's graph is the recording's graph of
frame t+k−1 (built by the workers like any other example, without noise) and the previous
step's answer enters it as a deviation from the recording:

- the previous answer's error, per dynamic vertex (its position less the recording's, its
  velocity less the recording's), is projected onto a rigid motion of each object, as the
  simulator's rollout projects its answers (`rigid_projection`: the least-squares rigid field
  about the recording's pose at t+k−1, which for the few centimetres of a step's error is the
  rollout's shape matching to first order);
- every feature of the step's graph that a dynamic node's position or velocity enters is
  shifted by that motion (`deviated_graph`): node velocities, mesh–object offsets, and the
  face–face edges' closest points (kept at their barycentric coordinates on each face),
  vertex offsets and normals; static nodes do not move. A vertex's velocity moves by the
  velocity error alone: that an object turned by θ moves its vertices a little differently
  with the same spin ω (by ω × (θ × r)) is left out;
- the step's targets are the recording's t+k less the previous answer's deviation. The part
  of frame t's noise the first target keeps (`TrainingSettings.target_keeps_noise`) is kept
  by every later target too, carried as the same vector per vertex. A step's error against
  its own (shifted) targets is then the deviation of its answer from the recording, which
  the next step takes.

The face pairs are the recording's: a pair the deviation brings inside the collision radius
(or takes out of it) is not added (or removed). A zero deviation gives the step's graph
features exactly (tests/core/model/test_unroll.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from fignetctl.core.model.graph import FACE_FACE, EdgeSet, MultiGraph, batch_graphs
from fignetctl.core.model.scene_graph import barycentric_weights
from fignetctl.errors import FignetError


@dataclasses.dataclass
class LaterStep:
    """What a later step (k ≥ 2) of one example (or a batch of them) needs beside its graph.

    graph : the recording's raw graph of frame t+k−1 (N nodes)
    first : (Vd,) rows of the previous step's predictions (and targets) that are this step's
        dynamic vertices, in the same order
    rows : (Vd,) the dynamic vertex nodes of `graph`
    object_rows : (Od,) the object nodes of `graph`, one per dynamic object
    vertex_object : (Vd,) the object (0 .. Od−1) of each dynamic vertex
    offsets : (Vd, 3) each dynamic vertex less its object's centre, at t+k−1
    inverse_normal : (Od, 6, 6) the pseudo-inverse of Σ Jᵀ J, J = [1, −[r]×], per object
    start : (Vd, 3) the first step's target position less the recording's at t+1 (the part of
        frame t's noise the targets keep)
    targets : (Vd, 6) the recording's raw targets of the step t+k−1 -> t+k
    weights : (Vd,) loss weight of each row
    sender_weights, receiver_weights : (E, 3) barycentric coordinates of each face–face edge's
        closest points on its (canonically ordered) faces
    sender_offsets, receiver_offsets : (E, 3, 3) the faces' vertices less their closest
        point, not clamped (for a face whose nearest vertex is clamped too, a floor's huge
        triangle, the clamped features, and its closest point at that vertex)
    offset_limits : (E,) the length vertex offsets are clamped to (inf: not clamped)
    sender_edges, receiver_edges : (E, 2, 3) each face's second and third vertex less its first
    normal_signs : (E, 2) +1 or −1, so sign · (edge 1 × edge 2) points as the feature's normal
    """

    graph: MultiGraph
    first: torch.Tensor
    rows: torch.Tensor
    object_rows: torch.Tensor
    vertex_object: torch.Tensor
    offsets: torch.Tensor
    inverse_normal: torch.Tensor
    start: torch.Tensor
    targets: torch.Tensor
    weights: torch.Tensor
    sender_weights: torch.Tensor
    receiver_weights: torch.Tensor
    sender_offsets: torch.Tensor
    receiver_offsets: torch.Tensor
    offset_limits: torch.Tensor
    sender_edges: torch.Tensor
    receiver_edges: torch.Tensor
    normal_signs: torch.Tensor

    def to(self, device) -> LaterStep:
        moved = {
            field.name: getattr(self, field.name).to(device)
            for field in dataclasses.fields(self)
            if field.name != "graph"
        }
        return LaterStep(graph=self.graph.to(device), **moved)


def check_unrollable(simulator_config) -> None:
    """Refuse models whose later-step features `deviated_graph` does not shift."""
    if not simulator_config.uses_velocities:
        raise FignetError(
            "a loss through several steps needs a velocity-state model, which carries its own velocities"
        )
    if simulator_config.free_motion or simulator_config.graph.contact_velocity:
        raise FignetError(
            "a loss through several steps does not follow the free-motion or contact-velocity inputs; "
            "train without them"
        )


def later_step(scene_graph, targets, geometry, positions, start, weights, max_vertex_offset) -> LaterStep:
    """The LaterStep of one example from the recording's `scene_graph` of frame t+k−1 and its
    raw `targets`; positions (O, 3) the centres at t+k−1; start (Vd, 3) and weights (a number or
    (Vd,)) as LaterStep's; `max_vertex_offset` the graph's (GraphConfig; None: no clamp)."""
    nodes = scene_graph.node_positions[1]
    num_dynamic = scene_graph.num_dynamic_vertex_nodes
    dynamic_objects = np.flatnonzero(~geometry.static)
    local = np.full(geometry.num_objects, -1, np.int64)
    local[dynamic_objects] = np.arange(len(dynamic_objects))
    vertex_object = local[geometry.vertex_object[geometry.dynamic_vertices]]
    offsets = nodes[:num_dynamic] - np.asarray(positions, np.float64)[dynamic_objects][vertex_object]
    faces = scene_graph.graph.edge_sets[FACE_FACE]
    senders, receivers = faces.senders.numpy(), faces.receivers.numpy()
    features = faces.features.numpy().astype(np.float64)
    limit = np.inf if max_vertex_offset is None else float(max_vertex_offset)
    sender = _face_geometry(nodes[senders], features[:, 4:16], limit)
    receiver = _face_geometry(nodes[receivers], features[:, 16:28], limit)
    signs = np.stack(
        [_normal_sign(sender[2], features[:, 28:31]), _normal_sign(receiver[2], features[:, 31:34])], axis=1
    )

    def tensor(values, dtype=torch.float32):
        return torch.as_tensor(np.array(values), dtype=dtype)

    return LaterStep(
        graph=scene_graph.graph,
        first=torch.arange(num_dynamic),
        rows=torch.arange(num_dynamic),
        object_rows=torch.from_numpy(np.flatnonzero(scene_graph.node_vertex < 0)),
        vertex_object=torch.from_numpy(vertex_object),
        offsets=tensor(offsets),
        inverse_normal=tensor(_inverse_normal_matrices(offsets, vertex_object, len(dynamic_objects))),
        start=tensor(start),
        targets=tensor(targets),
        weights=tensor(np.broadcast_to(np.asarray(weights, np.float64), (num_dynamic,))),
        sender_weights=tensor(sender[0]),
        receiver_weights=tensor(receiver[0]),
        sender_offsets=tensor(sender[1]),
        receiver_offsets=tensor(receiver[1]),
        offset_limits=tensor(np.full(len(features), limit)),
        sender_edges=tensor(sender[2]),
        receiver_edges=tensor(receiver[2]),
        normal_signs=tensor(signs),
    )


def _face_geometry(triangles, features, limit):
    """Barycentric weights (E, 3) of the closest point, offsets from it (E, 3, 3) and edges
    (E, 2, 3) of faces (E, 3, 3) in canonical order, from their 12 face–face columns (offsets
    of the three vertices from the closest point, clamped to `limit`, and their norms)."""
    given = features[:, :9].reshape(-1, 3, 3)
    exact = features[:, 9] < limit * (1 - 1e-5)  # the nearest vertex's offset is not clamped
    points = triangles[:, 0] - given[:, 0]
    offsets = np.where(exact[:, None, None], triangles - points[:, None], given)
    weights = np.where(exact[:, None], barycentric_weights(triangles, points), np.eye(3)[0])
    edges = triangles[:, 1:] - triangles[:, :1]
    return weights, offsets, edges


def _normal_sign(edges, normals):
    """+1 where edge 1 × edge 2 points along the feature's normal (or is zero), else −1."""
    return np.where(np.sum(np.cross(edges[:, 0], edges[:, 1]) * normals, axis=1) < 0, -1.0, 1.0)


def _inverse_normal_matrices(offsets, vertex_object, count):
    """(count, 6, 6) pinv(Σ_i J_iᵀ J_i) per object, J_i = [1, −[r_i]×]."""
    design = np.zeros((len(offsets), 3, 6))
    design[:, :, :3] = np.eye(3)
    x, y, z = offsets.T
    zero = np.zeros_like(x)
    cross = np.stack([[zero, -z, y], [z, zero, -x], [-y, x, zero]]).transpose(2, 0, 1)  # [r]×
    design[:, :, 3:] = -cross
    normal = np.zeros((count, 6, 6))
    np.add.at(normal, vertex_object, np.einsum("nki,nkj->nij", design, design))
    return np.linalg.pinv(normal, hermitian=True)


def batch_later_steps(steps, first_offsets) -> LaterStep:
    """The LaterSteps of a batch's examples as one (graphs batched, indices offset);
    `first_offsets`: where each example's rows start in the previous step's predictions."""
    node_offsets = np.cumsum([0] + [s.graph.num_nodes for s in steps[:-1]])
    object_offsets = np.cumsum([0] + [len(s.object_rows) for s in steps[:-1]])

    def joined(name, offsets=None):
        parts = [getattr(s, name) for s in steps]
        if offsets is not None:
            parts = [p + int(o) for p, o in zip(parts, offsets, strict=True)]
        return torch.cat(parts)

    return LaterStep(
        graph=batch_graphs([s.graph for s in steps]),
        first=joined("first", first_offsets),
        rows=joined("rows", node_offsets),
        object_rows=joined("object_rows", node_offsets),
        vertex_object=joined("vertex_object", object_offsets),
        **{
            name: joined(name)
            for name in (
                "offsets",
                "inverse_normal",
                "start",
                "targets",
                "weights",
                "sender_weights",
                "receiver_weights",
                "sender_offsets",
                "receiver_offsets",
                "offset_limits",
                "sender_edges",
                "receiver_edges",
                "normal_signs",
            )
        },
    )


def rigid_projection(deviation, vertex_object, offsets, inverse_normal):
    """(Vd, 3) per-vertex deviations -> the nearest rigid field δc + θ × r of each object, per
    vertex (Vd, 3), and its value at the centres δc (Od, 3)."""
    moments = torch.cat([deviation, torch.linalg.cross(offsets, deviation, dim=1)], dim=1)
    sums = torch.zeros(len(inverse_normal), 6, dtype=deviation.dtype, device=deviation.device)
    sums = sums.index_add(0, vertex_object, moments)
    solution = torch.einsum("oij,oj->oi", inverse_normal, sums)
    linear, angular = solution[:, :3], solution[:, 3:]
    return linear[vertex_object] + torch.linalg.cross(angular[vertex_object], offsets, dim=1), linear


def deviated_graph(step: LaterStep, position_shift, velocity_shift) -> MultiGraph:
    """The step's raw graph with its nodes moved by `position_shift` and their velocity
    changed by `velocity_shift` ((N, 3) each, per step, zero on static nodes)."""
    graph = step.graph
    nodes = graph.node_features
    pad = torch.zeros(len(nodes), nodes.shape[1] - 3, dtype=nodes.dtype, device=nodes.device)
    edge_sets = {}
    for name, edge_set in graph.edge_sets.items():
        if edge_set.is_hyper_edge_set:
            features = _face_face_features(step, edge_set, position_shift)
        else:
            vector = (
                edge_set.features[:, :3]
                + position_shift[edge_set.senders]
                - position_shift[edge_set.receivers]
            )
            features = torch.cat([vector, _norm(vector)[:, None], edge_set.features[:, 4:]], dim=1)
        edge_sets[name] = EdgeSet(name, features, edge_set.senders, edge_set.receivers)
    return MultiGraph(nodes + torch.cat([velocity_shift, pad], dim=1), edge_sets)


def _face_face_features(step: LaterStep, edge_set: EdgeSet, shift):
    """The 34 face–face columns (scene_graph.face_face_features) of faces moved by `shift`."""
    if edge_set.features.shape[1] != 34:
        raise FignetError(
            "a loss through several steps does not follow the contact-velocity inputs; train without them"
        )
    sender_shift, receiver_shift = shift[edge_set.senders], shift[edge_set.receivers]  # (E, 3, 3)
    sender_point = torch.einsum("ek,ekd->ed", step.sender_weights, sender_shift)
    receiver_point = torch.einsum("ek,ekd->ed", step.receiver_weights, receiver_shift)
    between = edge_set.features[:, :3] + receiver_point - sender_point
    sender = step.sender_offsets + sender_shift - sender_point[:, None]
    receiver = step.receiver_offsets + receiver_shift - receiver_point[:, None]
    sender_edges = step.sender_edges + sender_shift[:, 1:] - sender_shift[:, :1]
    receiver_edges = step.receiver_edges + receiver_shift[:, 1:] - receiver_shift[:, :1]
    return torch.cat(
        [
            between,
            _norm(between)[:, None],
            *_clamped_with_norms(sender, step.offset_limits),
            *_clamped_with_norms(receiver, step.offset_limits),
            _unit_normal(sender_edges, step.normal_signs[:, 0]),
            _unit_normal(receiver_edges, step.normal_signs[:, 1]),
        ],
        dim=1,
    )


def _clamped_with_norms(offsets, limits):
    """Offsets (E, 3, 3) shortened to at most `limits` (E,), directions kept, flat (E, 9), and
    their norms (E, 3)."""
    scale = torch.clamp(limits[:, None] / torch.clamp(_norm(offsets), min=1e-30), max=1.0)
    clamped = offsets * scale[..., None]
    return clamped.reshape(len(offsets), 9), _norm(clamped)


def _unit_normal(edges, signs):
    normal = torch.linalg.cross(edges[:, 0], edges[:, 1], dim=1) * signs[:, None]
    length = _norm(normal)
    return normal / torch.where(length > 0, length, torch.ones_like(length))[:, None]


def _norm(vectors):
    """Euclidean norm over the last axis, with a zero (not NaN) gradient at zero."""
    squares = torch.sum(vectors * vectors, dim=-1)
    positive = squares > 0
    return torch.where(positive, torch.sqrt(torch.where(positive, squares, torch.ones_like(squares))), 0.0)


def later_step_loss(simulator, previous_predictions, previous_targets, step: LaterStep, loss_of, autocast):
    """The loss of a later step, given the previous step's normalized predictions and raw
    targets; `loss_of(predictions, targets, weights=)` the regression loss, `autocast` a context
    for the network's pass. Returns the loss, and the step's normalized predictions (float) and
    raw targets, which the step after it takes."""
    graph, targets = later_step_inputs(simulator, previous_predictions, previous_targets, step)
    with autocast():
        predictions = simulator(graph, accumulate=False)[step.rows].float()
    normalized = simulator.normalized_targets(targets, accumulate=False)
    return loss_of(predictions, normalized, weights=step.weights), predictions, targets


def later_step_inputs(simulator, previous_predictions, previous_targets, step: LaterStep):
    """The step's raw graph and raw targets (Vd, 6), moved by the previous step's error.

    The first step's target keeps part of frame t's noise (`start`); each later step starts
    from it and its target keeps it too, so that only the network's own error is carried."""
    raw = simulator.acceleration_normalizer.inverse(previous_predictions[step.first])
    error = raw - previous_targets[step.first]

    def projected(deviation):
        return rigid_projection(deviation, step.vertex_object, step.offsets, step.inverse_normal)

    (position, centre), (noise, centre_noise) = projected(error[:, :3]), projected(step.start)
    velocity, centre_velocity = projected(error[:, 3:])
    nodes = step.graph.num_nodes
    position_shift = _placed(nodes, step.rows, position + noise, step.object_rows, centre + centre_noise)
    velocity_shift = _placed(nodes, step.rows, velocity, step.object_rows, centre_velocity)
    graph = deviated_graph(step, position_shift, velocity_shift)
    return graph, step.targets - torch.cat([position + velocity, velocity], dim=1)


def _placed(count, rows, values, object_rows, object_values):
    shift = torch.zeros(count, 3, dtype=values.dtype, device=values.device)
    return shift.index_copy(0, rows, values).index_copy(0, object_rows, object_values)
