"""Closest points between triangles, between segments, and from points to triangles.

These are the hot path of collision-edge construction, so everything is vectorised over a
batch of n independent queries and computed in float64. Public functions take and return
"vector-last" arrays, `(n, 3)` and `(n, 3, 3)`; internally the work is done on
"component-first" arrays, `(3, ...)`, so that each coordinate is one contiguous array and a
dot product is three multiplications, not a reduction over a short axis.

Triangle–triangle distance (`closest_points_triangles`) is the minimum over three kinds of
candidate point pairs, all of which are real points of the two triangles (so the minimum is
never below the true distance):

* the 6 vertex–triangle pairs: each vertex and its closest point on the other triangle;
* the 9 edge–edge pairs at the lines' mutual closest points, where these lie inside both
  edges. When they do not (parallel edges included), an endpoint is part of an optimal pair,
  and the vertex–triangle candidates already hold it;
* a crossing test: an edge of one triangle that pierces the other's face gives a common point
  (distance 0), the one case the first two cannot see.

Where the closest pair is not unique (parallel faces, intersecting triangles), the middle of
the extreme candidates is returned, so the answer does not depend on the vertex order and
does not flip with rounding when the scene is translated.

Zero-area triangles (segments, points) are handled as the union of their edges, so every
input with finite coordinates gives finite results.
"""

from __future__ import annotations

import numpy as np

# A triangle with |ab × ac|² <= DEGENERATE_AREA_RATIO · (longest edge)⁴ (its smallest height
# below 1e-8 of its longest edge) is treated as the union of its three edges: the error that
# makes is at most that height, and it avoids dividing by a vanishing area.
DEGENERATE_AREA_RATIO = 1e-16
# Pairs handled per vectorised pass: large enough to amortise numpy's per-call cost, small
# enough that the (3, 15, chunk) temporaries stay in cache.
PAIRS_PER_CHUNK = 2048
# Candidate pairs whose offset b - a differs from the best one's by at most TIE_TOLERANCE ·
# (size of the pair + its distance from the origin), i.e. by rounding, are ties; of ties, the
# middle of the two extreme ones along the planes' line of intersection (or
# TIE_BREAK_DIRECTION) is taken.
TIE_TOLERANCE = 1e-12
TIE_BREAK_DIRECTION = np.array([0.5773502691896258, 0.4472135954999579, 0.6832579001154006])


def _dot(u, v):
    """Dot product of component-first vectors: (3, ...) x (3, ...) -> (...)."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u, v):
    """Cross product of component-first vectors: (3, ...) x (3, ...) -> (3, ...)."""
    return np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def _clipped_ratio(numerator, denominator):
    """numerator / denominator clipped to [0, 1]; 0 where the denominator is not positive."""
    positive = denominator > 0.0
    ratio = numerator / np.where(positive, denominator, 1.0)
    return np.where(positive, np.clip(ratio, 0.0, 1.0), 0.0)


def _is_degenerate_triangle(edge_ab, edge_ac, edge_bc, normal):
    """True where a triangle's area is negligible against its longest edge.

    edge_ab, edge_ac, edge_bc, normal : (3, ...) float, normal = ab × ac
    returns : (...) bool
    """
    longest_squared = np.maximum(_dot(edge_ab, edge_ab), _dot(edge_ac, edge_ac))
    longest_squared = np.maximum(longest_squared, _dot(edge_bc, edge_bc))
    return _dot(normal, normal) <= DEGENERATE_AREA_RATIO * longest_squared * longest_squared


def _closest_point_on_segment_cf(points, starts, ends):
    """Closest point of each segment to each point (component-first, same shapes (3, ...))."""
    direction = ends - starts
    fraction = _clipped_ratio(_dot(points - starts, direction), _dot(direction, direction))
    return starts + fraction * direction


def _closest_point_on_edges_cf(points, a, b, c):
    """Closest point of the union of the three edges of triangles abc (component-first)."""
    candidates = np.stack(
        [
            _closest_point_on_segment_cf(points, a, b),
            _closest_point_on_segment_cf(points, b, c),
            _closest_point_on_segment_cf(points, c, a),
        ]
    )
    offsets = candidates - points[None]
    best = np.argmin(_dot(offsets.swapaxes(0, 1), offsets.swapaxes(0, 1)), axis=0)
    return np.take_along_axis(candidates, best[None, None], axis=0)[0]


def _ericson_region_coordinates(d1, d2, d3, d4, d5, d6):
    """Voronoi region of the query point and its (v, w) on ab, ac outside the face region.

    d1..d6 are Ericson's dot products (Real-Time Collision Detection, 5.1.5):
    d1, d2 = ab·ap, ac·ap; d3, d4 = ab·bp, ac·bp; d5, d6 = ab·cp, ac·cp.
    returns : v, w (...) float and interior (...) bool (the face region, handled by the caller)
    """
    vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
    in_vertex_a = (d1 <= 0.0) & (d2 <= 0.0)
    in_vertex_b = (d3 >= 0.0) & (d4 <= d3)
    in_edge_ab = (vc <= 0.0) & (d1 >= 0.0) & (d3 <= 0.0)
    in_vertex_c = (d6 >= 0.0) & (d5 <= d6)
    in_edge_ac = (vb <= 0.0) & (d2 >= 0.0) & (d6 <= 0.0)
    in_edge_bc = (va <= 0.0) & (d4 >= d3) & (d5 >= d6)
    fraction_ab = _clipped_ratio(d1, d1 - d3)
    fraction_ac = _clipped_ratio(d2, d2 - d6)
    fraction_bc = _clipped_ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    regions = [in_vertex_a, in_vertex_b, in_edge_ab, in_vertex_c, in_edge_ac, in_edge_bc]
    v = np.select(regions, [0.0, 1.0, fraction_ab, 0.0, 0.0, 1.0 - fraction_bc], 0.0)
    w = np.select(regions, [0.0, 0.0, 0.0, 1.0, fraction_ac, fraction_bc], 0.0)
    interior = ~(in_vertex_a | in_vertex_b | in_edge_ab | in_vertex_c | in_edge_ac | in_edge_bc)
    return v, w, interior


def _closest_point_on_triangle_cf(points, a, b, c):
    """Ericson's region method, component-first; degenerate triangles fall back to edges.

    Per-triangle quantities are computed at the triangles' shape and broadcast, so several
    query points per triangle cost little more than one. Ericson's d3..d6 come from d1, d2
    and the triangle's own dot products (d3 = d1 - ab·ab, ...). The face region uses the
    orthogonal projection p - n (n·ap)/|n|², which stays accurate for slivers, where
    Ericson's barycentric ratios lose digits to cancellation.

    points : (3, ...) float; a, b, c : (3, ...) float, broadcastable to points
    returns : (3, ...) float, the shape of points
    """
    ab, ac = b - a, c - a
    ab_ab, ab_ac, ac_ac = _dot(ab, ab), _dot(ab, ac), _dot(ac, ac)
    normal = _cross(ab, ac)
    normal_squared = _dot(normal, normal)
    ap = points - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    v, w, interior = _ericson_region_coordinates(d1, d2, d1 - ab_ab, d2 - ab_ac, d1 - ab_ac, d2 - ac_ac)
    height = _dot(normal, ap) / np.where(normal_squared > 0.0, normal_squared, 1.0)
    closest = np.where(interior, points - height * normal, a + v * ab + w * ac)
    degenerate = np.broadcast_to(_is_degenerate_triangle(ab, ac, c - b, normal), points.shape[1:])
    if degenerate.any():
        corners = [np.broadcast_to(corner, points.shape)[:, degenerate] for corner in (a, b, c)]
        closest[:, degenerate] = _closest_point_on_edges_cf(points[:, degenerate], *corners)
    return closest


def closest_point_on_triangle(points, triangles):
    """Closest point of each triangle to each point.

    Ericson's Voronoi-region method; triangles of (nearly) zero area are treated as the union
    of their edges (segment or point), so the result is always finite.

    points : (n, 3) float
    triangles : (n, 3, 3) float, triangle k has vertices triangles[k, 0..2]
    returns : (n, 3) float64
    """
    points = np.asarray(points, dtype=np.float64)
    triangles = np.asarray(triangles, dtype=np.float64)
    vertices_cf = np.moveaxis(triangles, -1, 0)
    points_cf, a, b, c = np.broadcast_arrays(np.moveaxis(points, -1, 0), *np.moveaxis(vertices_cf, -1, 0))
    return np.moveaxis(_closest_point_on_triangle_cf(points_cf, a, b, c), 0, -1)


def closest_points_segments(starts_1, ends_1, starts_2, ends_2):
    """Closest points between segments [p1, q1] and [p2, q2] (Ericson, 5.1.9), batched.

    Zero-length segments are points; parallel segments return one of the closest pairs.

    starts_1, ends_1, starts_2, ends_2 : (n, 3) float
    returns : point_1 (n, 3), point_2 (n, 3), distance (n,), all float64
    """
    ends = [np.moveaxis(np.asarray(x, dtype=np.float64), -1, 0) for x in (starts_1, ends_1, starts_2, ends_2)]
    p1, q1, p2, q2 = np.broadcast_arrays(*ends)
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, b, c, e, f = _dot(d1, d1), _dot(d1, d2), _dot(d1, r), _dot(d2, d2), _dot(d2, r)
    # The lines' optimum s = (bf - ce)/(ae - b²), written as n·(d2×r)/|n|² with n = d1×d2 so
    # that nearly parallel segments keep their digits; 0 for parallel or zero-length ones.
    normal = _cross(d1, d2)
    s = _clipped_ratio(_dot(normal, _cross(d2, r)), _dot(normal, normal))
    # The best t for that s; where t had to be clamped (or segment 2 is a point), the best s
    # for that t.
    t_unclamped = np.where(e > 0.0, (b * s + f) / np.where(e > 0.0, e, 1.0), 0.0)
    t = np.clip(t_unclamped, 0.0, 1.0)
    s = np.where((t_unclamped == t) & (e > 0.0), s, _clipped_ratio(b * t - c, a))
    point_1, point_2 = p1 + s * d1, p2 + t * d2
    distance = np.sqrt(_dot(point_1 - point_2, point_1 - point_2))
    return np.moveaxis(point_1, 0, -1), np.moveaxis(point_2, 0, -1), distance


def _vertex_face_candidates(vertices_a, vertices_b):
    """Each of the 6 vertices and its closest point on the other triangle.

    vertices_a, vertices_b : (3 coordinates, 3 vertices, n) float
    returns : points on a, points on b, each (3, 6, n)
    """
    # queries[:, 0] are a's vertices against face b, queries[:, 1] b's against face a.
    queries = np.stack([vertices_a, vertices_b], axis=1)
    faces = np.stack([vertices_b, vertices_a], axis=1)[:, :, :, None]
    closest = _closest_point_on_triangle_cf(queries, faces[:, :, 0], faces[:, :, 1], faces[:, :, 2])
    points_on_a = np.concatenate([vertices_a, closest[:, 1]], axis=1)
    points_on_b = np.concatenate([closest[:, 0], vertices_b], axis=1)
    return points_on_a, points_on_b


def _edge_edge_candidates(vertices_a, vertices_b):
    """For the 9 edge pairs, the lines' mutual closest points, where they lie on both edges.

    The line parameters use the cross-product form s = n·(d2×r)/|n|², t = n·(d1×r)/|n|²
    (n = d1×d2, r = p1-p2), which, unlike a·e-b², keeps its digits for nearly parallel edges.
    Where the lines' closest points fall outside an edge, or the edges are parallel or of
    zero length, an endpoint is part of the closest pair and the vertex–face candidates hold
    it: those edge pairs are marked not valid (their clamped points are still on the edges).

    vertices_a, vertices_b : (3 coordinates, 3 vertices, n) float
    returns : points on a, points on b, each (3, 9, n), and valid (9, n) bool;
              edge pair 3i+j = (edge i of a, edge j of b)
    """
    p1, p2 = vertices_a[:, :, None], vertices_b[:, None, :]
    d1 = np.roll(vertices_a, -1, axis=1)[:, :, None] - p1
    d2 = np.roll(vertices_b, -1, axis=1)[:, None, :] - p2
    r = p1 - p2
    normal = _cross(d1, d2)
    normal_squared = _dot(normal, normal)
    safe_squared = np.where(normal_squared > 0.0, normal_squared, 1.0)
    s = _dot(normal, _cross(d2, r)) / safe_squared
    t = _dot(normal, _cross(d1, r)) / safe_squared
    valid = (normal_squared > 0.0) & (s >= 0.0) & (s <= 1.0) & (t >= 0.0) & (t <= 1.0)
    s, t = np.clip(s, 0.0, 1.0), np.clip(t, 0.0, 1.0)
    shape = (3, 9, vertices_a.shape[-1])
    return (p1 + s * d1).reshape(shape), (p2 + t * d2).reshape(shape), valid.reshape(shape[1:])


def _points_inside_faces(points, corners, normals):
    """True where points (assumed in the face planes) lie inside the triangles, edges included.

    points : (3, k, m); corners : (3 coordinates, 3 vertices, m); normals : (3, m)
    returns : (k, m) bool
    """
    inside = np.ones(points.shape[1:], dtype=bool)
    for start, end in ((0, 1), (1, 2), (2, 0)):
        edge = (corners[:, end] - corners[:, start])[:, None]
        side = _dot(normals[:, None], _cross(edge, points - corners[:, start][:, None]))
        inside &= side >= 0.0
    return inside


def _triangle_normals(vertices):
    """(3, n) un-normalized normals (b - a) × (c - a) of (3, 3, n) component-first triangles."""
    return _cross(vertices[:, 1] - vertices[:, 0], vertices[:, 2] - vertices[:, 0])


def _straddles_plane(vertices, face_vertices, face_normals):
    """Where triangles lie strictly on both sides of the plane of a non-degenerate face.

    vertices, face_vertices : (3, 3, n); face_normals : (3, n)
    returns : side (3, n) the vertices' signed (scaled) distances to the planes,
              straddles (n,) bool, face_degenerate (n,) bool
    """
    origin = face_vertices[:, 0]
    side = _dot(face_normals[:, None], vertices - origin[:, None])
    sign = np.sign(side)
    edge_ab, edge_ac = face_vertices[:, 1] - origin, face_vertices[:, 2] - origin
    face_degenerate = _is_degenerate_triangle(edge_ab, edge_ac, edge_ac - edge_ab, face_normals)
    return side, (sign.min(axis=0) < 0) & (sign.max(axis=0) > 0) & ~face_degenerate, face_degenerate


def _face_plane_crossings(edge_triangles, face_triangles, face_normals, side):
    """Points of edge_triangles' boundary that lie on the face of face_triangles.

    These are the edges' crossings of the face's plane (vertices strictly on both sides)
    and the vertices exactly on the plane, kept where they fall inside the face.

    edge_triangles, face_triangles : (3 coordinates, 3 vertices, m) float
    face_normals : (3, m); side : (3, m) the edge triangles' signed distances to the planes
    returns : points (3, 6, m) float (3 crossings, then 3 vertices), valid (6, m) bool
    """
    sign = np.sign(side)
    crosses = sign * np.roll(sign, -1, axis=0) < 0
    fraction = side / np.where(crosses, side - np.roll(side, -1, axis=0), 1.0)
    crossings = edge_triangles + fraction * (np.roll(edge_triangles, -1, axis=1) - edge_triangles)
    points = np.concatenate([crossings, edge_triangles], axis=1)
    inside = _points_inside_faces(points, face_triangles, face_normals)
    return points, np.concatenate([crosses, sign == 0]) & inside


def _intersection_points(vertices_a, vertices_b, normals_a, normals_b):
    """Points where either triangle's boundary meets the other's face, for the pairs that can
    intersect across their planes (each straddles the other's plane, or is degenerate).

    vertices_a, vertices_b : (3 coordinates, 3 vertices, n) float; normals_a, normals_b : (3, n)
    returns : pairs (m,) int, points (3, 12, m) float, valid (12, m) bool
    """
    side_a, straddles_ab, degenerate_b = _straddles_plane(vertices_a, vertices_b, normals_b)
    side_b, straddles_ba, degenerate_a = _straddles_plane(vertices_b, vertices_a, normals_a)
    # Non-degenerate triangles can cross only if each straddles the other's plane; a
    # degenerate one (a segment) only needs to straddle the other's plane.
    may_cross = (straddles_ab | degenerate_b) & (straddles_ba | degenerate_a) & ~(degenerate_a & degenerate_b)
    pairs = np.flatnonzero(may_cross)
    if pairs.size == 0:
        return pairs, np.zeros((3, 12, 0)), np.zeros((12, 0), dtype=bool)
    a, b = vertices_a[..., pairs], vertices_b[..., pairs]
    points_ab, valid_ab = _face_plane_crossings(a, b, normals_b[:, pairs], side_a[:, pairs])
    points_ba, valid_ba = _face_plane_crossings(b, a, normals_a[:, pairs], side_b[:, pairs])
    valid = np.concatenate([valid_ab & straddles_ab[pairs], valid_ba & straddles_ba[pairs]])
    return pairs, np.concatenate([points_ab, points_ba], axis=1), valid


def _tie_break_directions(normals_a, normals_b):
    """(3, n) a direction along which to pick the extremes of a set of equally good points.

    For crossing planes it is the planes' line of intersection (n_a × n_b); for parallel or
    degenerate triangles, the fixed generic direction TIE_BREAK_DIRECTION.
    """
    line = _cross(normals_a, normals_b)
    crossing = _dot(line, line) > 1e-12 * _dot(normals_a, normals_a) * _dot(normals_b, normals_b)
    return np.where(crossing, line, TIE_BREAK_DIRECTION[:, None])


def _middle_of_extremes(points_a, points_b, usable, directions):
    """Mean of the usable pairs whose points on a are first and last along `directions`.

    points_a, points_b : (3, k, n); usable : (k, n) bool, at least one per column;
    directions : (3, n). returns : two (3, n)
    """
    along = _dot(directions[:, None], points_a)
    first = np.argmin(np.where(usable, along, np.inf), axis=0)[None, None]
    last = np.argmax(np.where(usable, along, -np.inf), axis=0)[None, None]
    middle_a = np.take_along_axis(points_a, first, axis=1) + np.take_along_axis(points_a, last, axis=1)
    middle_b = np.take_along_axis(points_b, first, axis=1) + np.take_along_axis(points_b, last, axis=1)
    return 0.5 * middle_a[:, 0], 0.5 * middle_b[:, 0]


def _tied_with_best(offsets, squared_distances, tolerances):
    """(15, n) True for candidates whose offset b - a is the best one's up to `tolerances`."""
    best = np.argmin(squared_distances, axis=0)[None, None]
    offset_gaps = offsets - np.take_along_axis(offsets, best, axis=1)
    return (_dot(offset_gaps, offset_gaps) <= tolerances**2) & np.isfinite(squared_distances)


def _intersection_midpoints(vertices_a, vertices_b, normals, contact_points, contact, directions):
    """The middle of the intersection segment of each pair of crossing triangles.

    The segment's ends are among the crossing points and the touching candidates
    (contact_points (3, 15, n) where contact (15, n)); its middle is a common point that
    depends neither on the vertex order nor on which ends rounding lets the tests find.

    normals : (normals_a, normals_b), each (3, n); directions : (3, n)
    returns : pairs (m,) int, the crossing pairs, and midpoints (3, m)
    """
    pairs, crossing_points, crossing_valid = _intersection_points(vertices_a, vertices_b, *normals)
    crossing = crossing_valid.any(axis=0)
    pairs, crossing_points = pairs[crossing], crossing_points[:, :, crossing]
    crossing_valid = crossing_valid[:, crossing]
    points = np.concatenate([contact_points[:, :, pairs], crossing_points], axis=1)
    usable = np.concatenate([contact[:, pairs], crossing_valid])
    midpoints, _ = _middle_of_extremes(points, points, usable, directions[:, pairs])
    return pairs, midpoints


def _closest_points_triangles_chunk(vertices_a, vertices_b, origin_norms):
    """closest_points_triangles on component-first arrays (3, 3, n); returns two (3, n).

    origin_norms (n,) is how far from the world origin the local frame lies, which sets how
    much rounding the inputs carry and so what counts as a tie (TIE_TOLERANCE).

    Every closest pair of two convex sets has the same offset b - a, so the mean of any two
    of them is one too. Where several candidates tie, i.e. have the best candidate's offset
    up to rounding (parallel faces, a contact segment), the middle of the extreme ones is
    returned: it depends neither on the vertex order nor on which candidate rounding happens
    to favour. Crossing triangles get the middle of their intersection segment.
    """
    vertex_on_a, vertex_on_b = _vertex_face_candidates(vertices_a, vertices_b)
    edge_on_a, edge_on_b, edge_valid = _edge_edge_candidates(vertices_a, vertices_b)
    candidates_a = np.concatenate([vertex_on_a, edge_on_a], axis=1)
    candidates_b = np.concatenate([vertex_on_b, edge_on_b], axis=1)
    offsets = candidates_b - candidates_a
    squared_distances = _dot(offsets, offsets)
    squared_distances[6:][~edge_valid] = np.inf
    pair_sizes = np.sqrt(np.maximum(_dot(vertices_a, vertices_a), _dot(vertices_b, vertices_b)).max(axis=0))
    tolerances = TIE_TOLERANCE * (pair_sizes + origin_norms)
    normals_a, normals_b = _triangle_normals(vertices_a), _triangle_normals(vertices_b)
    directions = _tie_break_directions(normals_a, normals_b)
    tied = _tied_with_best(offsets, squared_distances, tolerances)
    point_a, point_b = _middle_of_extremes(candidates_a, candidates_b, tied, directions)
    contact = squared_distances <= tolerances**2
    normals = (normals_a, normals_b)
    pairs, midpoints = _intersection_midpoints(
        vertices_a, vertices_b, normals, candidates_a, contact, directions
    )
    point_a[:, pairs], point_b[:, pairs] = midpoints, midpoints
    return point_a, point_b


def closest_points_triangles(triangles_a, triangles_b):
    """Closest points between triangles_a[k] and triangles_b[k] for each of n pairs.

    Correct for disjoint, touching, parallel, coplanar and intersecting triangles (distance 0
    and a common point) and for zero-area ones (segments, points); never NaN for finite input.
    Each pair is computed about its first vertex of a, so scenes far from the origin keep
    their precision.

    triangles_a, triangles_b : (n, 3, 3) float, [pair, vertex, coordinate]
    returns : point_a (n, 3) on triangles_a, point_b (n, 3) on triangles_b,
              distance (n,) = |point_a - point_b|, all float64
    """
    triangles_a = np.asarray(triangles_a, dtype=np.float64).reshape(-1, 3, 3)
    triangles_b = np.asarray(triangles_b, dtype=np.float64).reshape(-1, 3, 3)
    point_a, point_b = np.empty((2, triangles_a.shape[0], 3))
    for start in range(0, triangles_a.shape[0], PAIRS_PER_CHUNK):
        chunk = slice(start, start + PAIRS_PER_CHUNK)
        origin = triangles_a[chunk, :1]
        vertices_a = np.ascontiguousarray((triangles_a[chunk] - origin).transpose(2, 1, 0))
        vertices_b = np.ascontiguousarray((triangles_b[chunk] - origin).transpose(2, 1, 0))
        origin_norms = np.linalg.norm(origin[:, 0], axis=-1)
        local_a, local_b = _closest_points_triangles_chunk(vertices_a, vertices_b, origin_norms)
        point_a[chunk], point_b[chunk] = local_a.T + origin[:, 0], local_b.T + origin[:, 0]
    distance = np.linalg.norm(point_a - point_b, axis=-1)
    return point_a, point_b, distance
