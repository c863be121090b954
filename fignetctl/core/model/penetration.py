"""Keep dynamic objects out of static geometry: a geometric guard after each learned step.

The learned simulator predicts motion; nothing in it forbids a prediction that puts an object
into the floor, and an object that ends a step inside a static mesh is in a state the network
never saw in training, from which it does not recover (docs/simulator.md: objects up to
1.5 m into the floor after 200 steps). This guard enforces the one hard constraint the
ground truth never breaks, and only that:

For every vertex of a dynamic object, the segment from its position at t to its predicted
position at t+1 is tested against the faces of static objects (the floor, the environment,
objects asleep) near it. A vertex that starts on or in front of a face (signed distance
along the face's outward normal >= −`tolerance`) and ends behind it, crossing the face
inside the triangle, has passed into the static mesh. The object is then translated along
that face's normal by the depth of its deepest such vertex, and the test is repeated (up to
`MAX_ITERATIONS` times, for corners where two faces meet). Only the translation changes: the
predicted rotation and the tangential motion stay the network's, and the object's next
velocity (x_{t+1} − x_t) loses the part that went into the face, which is a fully inelastic
impact along the normal.

This is a continuous (swept) test of vertices against faces, so a fast object cannot tunnel
through a thin plate; edges of the static mesh poking into a dynamic face are not tested.
A vertex already behind a face by more than the tolerance at t (a scene that starts
interpenetrating) is left alone rather than dragged through.
"""

from __future__ import annotations

import numpy as np

from fignetctl.core.broadphase import BOUND_RELATIVE_SLACK
from fignetctl.core.model.scene_graph import unit_normals

TOLERANCE = 1e-3
"""Metres a vertex may be behind a face at t and still count as in front of it (rounding,
and a vertex left exactly on the surface by the previous correction)."""
MAX_ITERATIONS = 4
INSIDE_SLACK = 1e-9
"""Barycentric slack of the crossing test, so a vertex crossing exactly at a shared edge of
two faces is caught by one of them."""


def push_out_of_static(
    geometry, positions_now, quaternions_now, next_positions, next_quaternions, tolerance=TOLERANCE
):
    """Predicted poses at t+1 -> the same with each dynamic object translated out of the static
    meshes its vertices passed into during the step (module docstring).

    positions_now (O, 3), quaternions_now (O, 4): poses at t; next_positions (O, 3),
    next_quaternions (O, 4): poses at t+1, static objects at their pose at t+1.
    returns (O, 3) float64 positions (a copy) and (O,) float64 the translation's length per object
    """
    next_positions = np.array(next_positions, np.float64)
    shifts = np.zeros(geometry.num_objects)
    static_objects = np.flatnonzero(geometry.static)
    if static_objects.size == 0:
        return next_positions, shifts
    groups = [geometry.static_face_group(o, next_positions, next_quaternions) for o in static_objects]
    for o in np.flatnonzero(~geometry.static):
        vertices = geometry.object_vertices[o]
        start = geometry.world_vertices(positions_now, quaternions_now, vertices)
        end = geometry.world_vertices(next_positions, next_quaternions, vertices)
        total = np.zeros(3)
        for _ in range(MAX_ITERATIONS):
            push = deepest_crossing(groups, start, end + total, tolerance)
            if push is None:
                break
            total += push
        next_positions[o] += total
        shifts[o] = np.linalg.norm(total)
    return next_positions, shifts


def deepest_crossing(groups, start, end, tolerance):
    """The translation (3,) that brings the deepest vertex crossing back onto its face, or
    None when no vertex segment start -> end (n, 3) passes into a face of `groups`."""
    best_depth, best_push = 0.0, None
    for group in groups:
        vertex, local = _candidate_pairs(group, start, end, tolerance)
        if vertex.size == 0:
            continue
        triangles = group.triangles(local)
        normals = unit_normals(triangles)  # outward (counter-clockwise seen from outside); zero if degenerate
        a = triangles[:, 0]
        s0 = np.einsum("pj,pj->p", normals, start[vertex] - a)
        s1 = np.einsum("pj,pj->p", normals, end[vertex] - a)
        crossing = normals.any(axis=1) & (s0 >= -tolerance) & (s1 < 0)
        fraction = np.clip(np.divide(s0, s0 - s1, out=np.zeros_like(s0), where=crossing), 0.0, 1.0)
        point = start[vertex] + fraction[:, None] * (end[vertex] - start[vertex])
        crossing &= _inside(triangles, normals, point)
        if crossing.any():
            k = np.argmax(np.where(crossing, -s1, -np.inf))
            if -s1[k] > best_depth:
                best_depth, best_push = -s1[k], -s1[k] * normals[k]
    return best_push


def _candidate_pairs(group, start, end, tolerance):
    """(vertex rows, local face rows) whose segment and face bounding spheres may meet."""
    midpoints = 0.5 * (start + end)
    half_lengths = 0.5 * np.linalg.norm(end - start, axis=1) + tolerance
    found_vertex, found_local = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for rows, largest, tree in group.classes():
        reach = (half_lengths + largest) * (1.0 + BOUND_RELATIVE_SLACK)
        hits = tree.query_ball_point(midpoints, reach)
        counts = np.array([len(h) for h in hits])
        if counts.sum() == 0:
            continue
        found_vertex.append(np.repeat(np.arange(len(start)), counts))
        found_local.append(rows[np.concatenate([np.asarray(h, np.int64) for h in hits])])
    return np.concatenate(found_vertex), np.concatenate(found_local)


def _inside(triangles, normals, points):
    """(P,) True where each point, projected on its triangle's plane, lies in the triangle."""
    inside = np.ones(len(points), bool)
    for i in range(3):
        a, b = triangles[:, i], triangles[:, (i + 1) % 3]
        edge_normal = np.cross(b - a, normals)  # points out of the triangle across edge a-b
        scale = np.linalg.norm(b - a, axis=1) ** 2
        inside &= np.einsum("pj,pj->p", points - a, edge_normal) <= INSIDE_SLACK * scale
    return inside
