"""Closest points between triangles, segments and points, against independent references.

References: dense barycentric sampling of both triangles (bounds the distance from both
sides), non-negative least squares (is a returned point on its triangle?), and the convex
optimality condition (pa, pb) is a closest pair of convex sets A, B iff, with d = pb - pa,
(x - pa)·d <= 0 for every vertex x of A and (y - pb)·d >= 0 for every vertex y of B.
"""

import numpy as np
import pytest
from scipy.optimize import nnls

from fignetctl.core.triangles import (
    PAIRS_PER_CHUNK,
    closest_point_on_triangle,
    closest_points_segments,
    closest_points_triangles,
)

SAMPLING_SUBDIVISIONS = 12
SAMPLING_CHUNK = 64
SEGMENT_SAMPLES = 201


# ----------------------------------------------------------------------------- references


def barycentric_grid(subdivisions):
    """(K, 3) barycentric weights of a regular grid with `subdivisions` steps per edge."""
    i, j = np.meshgrid(np.arange(subdivisions + 1), np.arange(subdivisions + 1), indexing="ij")
    keep = i + j <= subdivisions
    i, j = i[keep], j[keep]
    return np.stack([subdivisions - i - j, i, j], axis=-1) / subdivisions


def sampled_min_distance(triangles_a, triangles_b, subdivisions=SAMPLING_SUBDIVISIONS):
    """(n,) smallest distance between the dense samples of each pair of triangles."""
    weights = barycentric_grid(subdivisions)
    result = np.empty(triangles_a.shape[0])
    for start in range(0, triangles_a.shape[0], SAMPLING_CHUNK):
        chunk = slice(start, start + SAMPLING_CHUNK)
        samples_a = np.einsum("kv,nvj->nkj", weights, triangles_a[chunk])
        samples_b = np.einsum("kv,nvj->nkj", weights, triangles_b[chunk])
        gaps = samples_a[:, :, None, :] - samples_b[:, None, :, :]
        result[chunk] = np.sqrt(np.einsum("nabj,nabj->nab", gaps, gaps).min(axis=(1, 2)))
    return result


def longest_edge(triangles):
    """(n,) longest edge length of each triangle."""
    edges = triangles - np.roll(triangles, 1, axis=1)
    return np.linalg.norm(edges, axis=-1).max(axis=-1)


def distance_to_convex_hull_nnls(point, corners):
    """Distance from a point to the convex hull of a few corners, by non-negative least squares.

    Computed about the first corner in units of the hull's size; the affine constraint
    sum(weights) = 1 is a heavily weighted extra row.
    """
    size = max(np.abs(corners - corners[0]).max(), np.abs(point - corners[0]).max(), 1e-300)
    local_corners, local_point = (corners - corners[0]) / size, (point - corners[0]) / size
    matrix = np.vstack([local_corners.T, np.full(corners.shape[0], 1e4)])
    weights, _ = nnls(matrix, np.append(local_point, 1e4))
    return np.linalg.norm(local_corners.T @ weights - local_point) * size


def optimality_violation(corners_a, corners_b, point_a, point_b):
    """(n,) how much the convex optimality condition fails, relative to the pair's size.

    Pairs closer than 1e-12 of their size count as touching (their direction is rounding).
    """
    direction = point_b - point_a
    beyond_a = np.einsum("nkj,nj->nk", corners_a - point_a[:, None], direction).max(axis=1)
    before_b = -np.einsum("nkj,nj->nk", corners_b - point_b[:, None], direction).min(axis=1)
    corners = np.concatenate([corners_a, corners_b], axis=1)
    size = np.linalg.norm(corners.max(axis=1) - corners.min(axis=1), axis=-1) + 1e-300
    gap = np.linalg.norm(direction, axis=-1)
    touching = gap <= 1e-12 * size
    return np.where(touching, 0.0, np.maximum(beyond_a, before_b) / (size * np.where(touching, 1.0, gap)))


# ---------------------------------------------------------------------------- test cases


def in_plane_frames(triangles):
    """Unit in-plane axes (u, v) and unit normal w of non-degenerate triangles, each (n, 3)."""
    u = triangles[:, 1] - triangles[:, 0]
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    w = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    w /= np.linalg.norm(w, axis=-1, keepdims=True)
    return u, np.cross(w, u), w


def random_directions(rng, count):
    """(count, 3) unit vectors."""
    directions = rng.normal(size=(count, 3))
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


def generic_pairs(rng, count):
    """Random triangles, many intersecting, many apart."""
    shifts = rng.normal(0, 0.8, (count, 1, 3))
    return rng.uniform(-1, 1, (count, 3, 3)), rng.uniform(-1, 1, (count, 3, 3)) + shifts


def degenerate_triangles(rng, count):
    """Collinear, coincident-vertex, point, sliver and needle triangles (cycled)."""
    a, b = rng.uniform(-1, 1, (2, count, 3))
    fraction = rng.uniform(-0.5, 1.5, (count, 1))
    perpendicular = np.cross(b - a, random_directions(rng, count))
    tiny = 10.0 ** rng.uniform(-12, -2, (count, 1))
    c_choices = [
        a + fraction * (b - a),  # collinear
        a.copy(),  # coincident vertices
        a.copy(),  # a point (b is reset below)
        a + fraction * (b - a) + tiny * perpendicular,  # sliver
        a + tiny * random_directions(rng, count),  # needle (a, c nearly coincide)
    ]
    kind = np.arange(count) % len(c_choices)
    c = np.choose(kind[:, None], c_choices)
    b = np.where((kind == 2)[:, None], a, b)
    vertex_order = rng.permuted(np.tile([0, 1, 2], (count, 1)), axis=1)
    return np.take_along_axis(np.stack([a, b, c], axis=1), vertex_order[:, :, None], axis=1)


def degenerate_pairs(rng, count):
    """Degenerate triangles against random ones and against each other."""
    half = count // 2
    generic_a, _ = generic_pairs(rng, half)
    shifted = degenerate_triangles(rng, count - half) + rng.normal(0, 0.3, (count - half, 1, 3))
    return (
        np.concatenate([generic_a, degenerate_triangles(rng, count - half)]),
        np.concatenate([degenerate_triangles(rng, half) * 0.7, shifted]),
    )


def parallel_pairs(rng, count):
    """B lies in a plane parallel to A's, at a gap of 0 (coplanar) for half of them."""
    triangles_a = rng.uniform(-1, 1, (count, 3, 3))
    u, v, w = in_plane_frames(triangles_a)
    in_plane = rng.uniform(-1, 1, (count, 3, 2))
    gap = np.where(np.arange(count) % 2 == 0, 0.0, rng.uniform(0, 0.5, count))
    triangles_b = (
        triangles_a[:, :1]
        + in_plane[..., :1] * u[:, None]
        + in_plane[..., 1:] * v[:, None]
        + gap[:, None, None] * w[:, None]
    )
    return triangles_a, triangles_b


def random_interior_points(rng, triangles):
    """(n, 3) a random point strictly inside each triangle."""
    weights = rng.dirichlet([2.0, 2.0, 2.0], size=triangles.shape[0])
    return np.einsum("nv,nvj->nj", weights, triangles)


def touching_pairs(rng, count):
    """B's vertex on A's face, or B's edge through a point of A's edge: distance 0."""
    triangles_a = rng.uniform(-1, 1, (count, 3, 3))
    _, _, normal = in_plane_frames(triangles_a)
    on_face = random_interior_points(rng, triangles_a)
    on_edge = triangles_a[:, 0] + rng.uniform(0, 1, (count, 1)) * (triangles_a[:, 1] - triangles_a[:, 0])
    above = normal * rng.uniform(0.1, 1, (count, 1))
    direction = random_directions(rng, count) * 0.5
    vertex_on_face = np.stack([on_face, on_face + above + direction, on_face + above - direction], axis=1)
    edge_through_edge = np.stack([on_edge + direction, on_edge - direction, on_edge + above], axis=1)
    use_face = (np.arange(count) % 2 == 0)[:, None, None]
    return triangles_a, np.where(use_face, vertex_on_face, edge_through_edge)


def intersecting_pairs(rng, count):
    """B (a triangle, or a zero-area segment) pierces A's face at a known point: distance 0."""
    triangles_a = rng.uniform(-1, 1, (count, 3, 3))
    _, _, normal = in_plane_frames(triangles_a)
    crossing = random_interior_points(rng, triangles_a)
    through = (normal + 0.5 * random_directions(rng, count)) * rng.uniform(0.05, 1, (count, 1))
    side = random_directions(rng, count) * rng.uniform(0.05, 1, (count, 1))
    # crossing = (B0 + B1/2 + B2/2)/2, so it lies inside B; B0 and B1, B2 are on opposite sides.
    triangle_b = np.stack([crossing + through, crossing - through + side, crossing - through - side], axis=1)
    segment_b = np.stack([crossing + through, crossing - through, crossing + 0.3 * through], axis=1)
    use_triangle = (np.arange(count) % 3 != 0)[:, None, None]
    return triangles_a, np.where(use_triangle, triangle_b, segment_b)


def all_pairs(seed=0, count_per_kind=500):
    """(triangles_a, triangles_b, touching (n,) bool) over every kind above."""
    rng = np.random.default_rng(seed)
    kinds = [generic_pairs, degenerate_pairs, parallel_pairs, touching_pairs, intersecting_pairs]
    pairs = [kind(rng, count_per_kind) for kind in kinds]
    touches = [kind in (touching_pairs, intersecting_pairs) for kind in kinds]
    touching = np.repeat(touches, count_per_kind)
    return np.concatenate([a for a, _ in pairs]), np.concatenate([b for _, b in pairs]), touching


@pytest.fixture(scope="module")
def pairs_and_result():
    triangles_a, triangles_b, touching = all_pairs()
    return triangles_a, triangles_b, touching, closest_points_triangles(triangles_a, triangles_b)


# ------------------------------------------------------------------------ triangle–triangle


def test_distance_agrees_with_dense_sampling(pairs_and_result):
    triangles_a, triangles_b, _, (_, _, distance) = pairs_and_result
    sampled = sampled_min_distance(triangles_a, triangles_b)
    resolution = (longest_edge(triangles_a) + longest_edge(triangles_b)) / SAMPLING_SUBDIVISIONS
    assert np.all(distance <= sampled + 1e-11)
    assert np.all(distance >= sampled - resolution - 1e-12)


def test_closest_pair_satisfies_the_optimality_condition(pairs_and_result):
    triangles_a, triangles_b, _, (point_a, point_b, _) = pairs_and_result
    assert optimality_violation(triangles_a, triangles_b, point_a, point_b).max() < 1e-7


def test_points_lie_on_their_triangles_and_distance_is_their_gap(pairs_and_result):
    triangles_a, triangles_b, _, (point_a, point_b, distance) = pairs_and_result
    assert np.allclose(np.linalg.norm(point_a - point_b, axis=-1), distance, rtol=0, atol=1e-14)
    for k in range(0, triangles_a.shape[0], 5):
        assert distance_to_convex_hull_nnls(point_a[k], triangles_a[k]) < 1e-9
        assert distance_to_convex_hull_nnls(point_b[k], triangles_b[k]) < 1e-9


def test_touching_and_intersecting_pairs_have_distance_zero(pairs_and_result):
    _, _, touching, (point_a, point_b, distance) = pairs_and_result
    assert np.all(distance[touching] < 1e-11)
    assert np.allclose(point_a[touching], point_b[touching], atol=1e-12)


def test_results_are_finite_for_every_kind(pairs_and_result):
    *_, (point_a, point_b, distance) = pairs_and_result
    assert np.isfinite(point_a).all() and np.isfinite(point_b).all() and np.isfinite(distance).all()


def test_known_distances():
    unit = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    lifted = unit + [0.0, 0, 0.5]
    skew_a = np.array([[-1.0, 0, 0], [1, 0, 0], [0, -1, -1]])
    skew_b = np.array([[0.0, -1, 1], [0, 1, 1], [1, 0, 2]])
    far_vertex = np.array([[0.2, 0.2, 3.0], [5, 5, 4], [6, 4, 5]])
    _, _, distance = closest_points_triangles(
        np.stack([unit, skew_a, unit, unit]), np.stack([lifted, skew_b, far_vertex, unit])
    )
    assert np.allclose(distance, [0.5, 1.0, 3.0, 0.0], atol=1e-15)


def test_swapping_and_reordering_vertices_keeps_the_distance(pairs_and_result):
    triangles_a, triangles_b, _, (_point_a, _point_b, distance) = pairs_and_result
    _swapped_b, _swapped_a, swapped_distance = closest_points_triangles(triangles_b, triangles_a)
    assert np.allclose(swapped_distance, distance, atol=1e-12)
    _, _, reordered = closest_points_triangles(triangles_a[:, [2, 0, 1]], triangles_b[:, [1, 0, 2]])
    assert np.allclose(reordered, distance, atol=1e-12)


@pytest.mark.parametrize("kind", [generic_pairs, touching_pairs, intersecting_pairs])
def test_closest_points_do_not_depend_on_vertex_order(kind):
    triangles_a, triangles_b = kind(np.random.default_rng(7), 400)
    point_a, point_b, _ = closest_points_triangles(triangles_a, triangles_b)
    for order_a, order_b in (([1, 2, 0], [2, 0, 1]), ([2, 1, 0], [0, 2, 1])):
        moved_a, moved_b, _ = closest_points_triangles(triangles_a[:, order_a], triangles_b[:, order_b])
        assert np.allclose(moved_a, point_a, atol=1e-9) and np.allclose(moved_b, point_b, atol=1e-9)


@pytest.mark.parametrize("gap", [0.0, 0.01])
def test_parallel_contact_points_are_canonical(gap):
    """A box's bottom faces over floor faces: many closest pairs tie; the choice must not
    depend on vertex order or on a translation of the scene."""
    rng = np.random.default_rng(8)
    floor = np.array([[[-5.0, -5, 0], [5, -5, 0], [5, 5, 0]], [[-5.0, -5, 0], [5, 5, 0], [-5, 5, 0]]])
    bottom = np.array([[[0.0, 0, 0], [0.4, 0, 0], [0.4, 0.4, 0]], [[0.0, 0, 0], [0.4, 0.4, 0], [0, 0.4, 0]]])
    bottoms = bottom[None] + np.c_[rng.uniform(-1, 1, (50, 2)), np.full(50, gap)][:, None, None]
    triangles_a, triangles_b = np.repeat(floor[None], 50, axis=0).reshape(-1, 3, 3), bottoms.reshape(-1, 3, 3)
    point_a, point_b, distance = closest_points_triangles(triangles_a, triangles_b)
    assert np.all(distance >= gap - 1e-15) and np.mean(np.abs(distance - gap) < 1e-15) > 0.3
    reordered = closest_points_triangles(triangles_a[:, [1, 2, 0]], triangles_b[:, [2, 1, 0]])
    reordered_a, reordered_b = reordered[0], reordered[1]
    assert np.allclose(reordered_a, point_a, atol=1e-12)
    assert np.allclose(reordered_b, point_b, atol=1e-12)
    offset = np.array([1000.0, -2000.0, 30.0])
    moved_a, moved_b, _ = closest_points_triangles(triangles_a + offset, triangles_b + offset)
    assert np.allclose(moved_a - offset, point_a, atol=1e-9)
    assert np.allclose(moved_b - offset, point_b, atol=1e-9)


def test_far_from_the_origin_keeps_precision():
    triangles_a, triangles_b, _ = all_pairs(seed=1, count_per_kind=100)
    _, _, near = closest_points_triangles(triangles_a, triangles_b)
    offset = np.array([3.0e4, -2.0e4, 1.0e4])
    point_a, _, far = closest_points_triangles(triangles_a + offset, triangles_b + offset)
    assert np.allclose(far, near, atol=1e-9)
    assert np.isfinite(point_a).all()


def test_chunked_batches_match_single_pairs():
    triangles_a, triangles_b = generic_pairs(np.random.default_rng(2), PAIRS_PER_CHUNK + 7)
    _, _, batched = closest_points_triangles(triangles_a, triangles_b)
    picks = [0, PAIRS_PER_CHUNK - 1, PAIRS_PER_CHUNK, PAIRS_PER_CHUNK + 6]
    singles = [closest_points_triangles(triangles_a[k : k + 1], triangles_b[k : k + 1])[2][0] for k in picks]
    assert np.array_equal(batched[picks], singles)


def test_empty_batch_gives_empty_arrays():
    point_a, point_b, distance = closest_points_triangles(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)))
    assert point_a.shape == (0, 3) and point_b.shape == (0, 3) and distance.shape == (0,)


def test_edges_crossing_at_a_tiny_angle_touch():
    angle = 1e-9
    triangles_a = np.array([[[-1.0, -angle, 0], [1, angle, 0], [0, 0, 1]]])
    triangles_b = np.array([[[-1.0, angle, 0], [1, -angle, 0], [0, 0, -1]]])
    _, _, distance = closest_points_triangles(triangles_a, triangles_b)
    assert distance[0] < 1e-15


# ---------------------------------------------------------------------- point–triangle


def test_closest_point_on_triangle_against_references():
    rng = np.random.default_rng(3)
    triangles = np.concatenate([rng.uniform(-1, 1, (600, 3, 3)), degenerate_triangles(rng, 600)])
    points = rng.uniform(-2, 2, (1200, 3))
    closest = closest_point_on_triangle(points, triangles)
    samples = np.einsum("kv,nvj->nkj", barycentric_grid(40), triangles)
    sampled = np.linalg.norm(samples - points[:, None], axis=-1).min(axis=1)
    distance = np.linalg.norm(closest - points, axis=-1)
    assert np.all(distance <= sampled + 1e-11)
    assert np.all(distance >= sampled - longest_edge(triangles) / 40 - 1e-12)
    # Optimality for a point and a convex set: (x - closest)·(point - closest) <= 0 for all x.
    slack = np.einsum("nkj,nj->nk", triangles - closest[:, None], points - closest).max(axis=1)
    assert np.all(slack <= 1e-9 * np.maximum(distance, 1e-12))
    assert all(distance_to_convex_hull_nnls(closest[k], triangles[k]) < 1e-9 for k in range(0, 1200, 10))


def test_closest_point_on_a_point_triangle_is_that_point():
    triangles = np.full((2, 3, 3), 0.25)
    closest = closest_point_on_triangle(np.array([[1.0, 2, 3], [0.25, 0.25, 0.25]]), triangles)
    assert np.array_equal(closest, np.full((2, 3), 0.25))


# --------------------------------------------------------------------------- segments


def segment_cases(rng, count):
    """Random, parallel, collinear, zero-length and crossing segment pairs (cycled)."""
    p1, q1, p2, q2 = rng.uniform(-1, 1, (4, count, 3))
    kind = np.arange(count) % 5
    shift = rng.normal(0, 0.3, (count, 3))
    q2 = np.where((kind == 1)[:, None], p2 + (q1 - p1) * rng.uniform(-1, 1, (count, 1)), q2)  # parallel
    p2 = np.where((kind == 2)[:, None], p1 + (q1 - p1) * 0.5, p2)  # collinear overlap
    q2 = np.where((kind == 2)[:, None], q1 + (q1 - p1), q2)
    q1 = np.where((kind == 3)[:, None], p1, q1)  # segment 1 is a point
    p2 = np.where((kind == 4)[:, None], 0.5 * (p1 + q1) + shift, p2)  # crossing at the middle
    q2 = np.where((kind == 4)[:, None], 0.5 * (p1 + q1) - shift, q2)
    return p1, q1, p2, q2


def sampled_min_segment_distance(p1, q1, p2, q2, samples):
    """(n,) smallest distance between `samples` evenly spaced points of each segment."""
    steps = np.linspace(0, 1, samples)[None, :, None]
    result = np.empty(p1.shape[0])
    for start in range(0, p1.shape[0], SAMPLING_CHUNK):
        chunk = slice(start, start + SAMPLING_CHUNK)
        samples_1 = p1[chunk, None] + steps * (q1 - p1)[chunk, None]
        samples_2 = p2[chunk, None] + steps * (q2 - p2)[chunk, None]
        gaps = samples_1[:, :, None] - samples_2[:, None]
        result[chunk] = np.sqrt(np.einsum("nabj,nabj->nab", gaps, gaps).min(axis=(1, 2)))
    return result


def test_closest_points_segments_against_dense_sampling():
    rng = np.random.default_rng(4)
    p1, q1, p2, q2 = segment_cases(rng, 500)
    point_1, point_2, distance = closest_points_segments(p1, q1, p2, q2)
    sampled = sampled_min_segment_distance(p1, q1, p2, q2, SEGMENT_SAMPLES)
    resolution = (np.linalg.norm(q1 - p1, axis=-1) + np.linalg.norm(q2 - p2, axis=-1)) / (SEGMENT_SAMPLES - 1)
    assert np.all(distance <= sampled + 1e-12) and np.all(distance >= sampled - resolution - 1e-12)
    assert np.allclose(np.linalg.norm(point_1 - point_2, axis=-1), distance, atol=1e-14)
    assert np.all(distance[4::5] < 1e-12)
    # Each point is on its segment: collinear with the ends and between them.
    for start, end, point in ((p1, q1, point_1), (p2, q2, point_2)):
        gap = np.linalg.norm(point - start, axis=-1) + np.linalg.norm(point - end, axis=-1)
        assert np.allclose(gap, np.linalg.norm(end - start, axis=-1), atol=1e-9)


def test_segments_crossing_at_a_tiny_angle_and_zero_length():
    angle = 1e-10
    starts_1, ends_1 = np.array([[-1.0, -angle, 0], [0, 0, 0]]), np.array([[1.0, angle, 0], [0, 0, 0]])
    starts_2, ends_2 = np.array([[-1.0, angle, 0], [0, 0, 2]]), np.array([[1.0, -angle, 0], [0, 0, 2]])
    point_1, point_2, distance = closest_points_segments(starts_1, ends_1, starts_2, ends_2)
    assert distance[0] < 1e-15 and np.allclose(point_1[0], 0, atol=1e-12)
    assert distance[1] == 2.0 and np.array_equal(point_2[1], [0.0, 0, 2])
