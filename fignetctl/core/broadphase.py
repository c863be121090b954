"""Pairs of faces of different objects within a collision radius, without the all-pairs cost.

A face–face collision edge joins two faces of different objects whose triangle–triangle
distance is at most the collision radius. Static–static pairs never get an edge (the floor
and the environment do not collide with each other), so they are never even looked at.

`face_pairs_within_radius` finds candidates with k-d trees over face centres and then keeps
exactly the pairs that `closest_points_triangles` puts within the radius:

1. Each face is bounded by a sphere about its centroid (radius r_i). Two faces can be within
   the radius R only if |c_i - c_j| <= R + r_i + r_j.
2. Only object pairs that are not both static and whose bounding boxes, grown by R, overlap
   are looked at: far-apart objects cost one box test, and static–static pairs nothing, so
   the cost follows the moving geometry, not the size of the static scene.
3. Faces differ wildly in size (a floor of 2 huge triangles beside small object faces), so
   each object's faces are grouped into size classes by powers of two of r_i, each with a
   k-d tree of centres. For each pair of classes (k, l) of the two objects, one tree query
   with the class bound R + max r_k + max r_l returns a superset, which the per-pair sphere
   test and an axis-aligned box test (boxes grown by R) then thin out. A huge face is thus
   only tested with a bound of its own size, never inserted into a grid of small cells.
4. The exact distance decides, computed for each pair in the order (lower face index,
   higher) exactly as the brute force does. The bounds in 1–3 carry a small relative slack,
   so a pair at exactly the radius is never lost to rounding, and the result equals
   `brute_force_face_pairs` bit for bit.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fignetctl.core.triangles import closest_points_triangles

# Relative and absolute slack on the conservative bounds (not on the exact test).
BOUND_RELATIVE_SLACK = 1e-9
BOUND_ABSOLUTE_SLACK = 1e-12
# Faces smaller than 2**-SIZE_CLASS_DEPTH of the largest share the last size class.
SIZE_CLASS_DEPTH = 20
# Candidate pairs checked exactly per pass of the brute-force reference.
BRUTE_FORCE_PAIRS_PER_PASS = 1 << 20


def _face_static_flags(face_object, object_static):
    """(F,) bool: True for faces of static objects (all False when object_static is None)."""
    face_object = np.asarray(face_object, dtype=np.int64)
    if object_static is None:
        return np.zeros(face_object.shape[0], dtype=bool)
    return np.asarray(object_static, dtype=bool)[face_object]


def _sorted_unique_pairs(face_i, face_j, face_count):
    """Order each pair as (min, max), drop duplicates, sort lexicographically."""
    low, high = np.minimum(face_i, face_j), np.maximum(face_i, face_j)
    keys = np.unique(low.astype(np.int64) * face_count + high)
    return keys // face_count, keys % face_count


def _pairs_within_exact_distance(triangles, face_i, face_j, radius):
    """The candidate pairs whose exact triangle–triangle distance is <= radius."""
    if face_i.size == 0:
        return face_i, face_j
    _, _, distance = closest_points_triangles(triangles[face_i], triangles[face_j])
    keep = distance <= radius
    return face_i[keep], face_j[keep]


def _candidate_filter(face_object, face_static, face_i, face_j):
    """True for pairs of different objects that are not both static."""
    return (face_object[face_i] != face_object[face_j]) & ~(face_static[face_i] & face_static[face_j])


def brute_force_face_pairs(triangles, face_object, radius, object_static=None):
    """Reference for `face_pairs_within_radius`: the exact distance of every eligible pair.

    O(F²) work; for tests and benchmarks only.

    triangles : (F, 3, 3) float
    face_object : (F,) int, the object of each face
    radius : float
    object_static : (O,) bool or None
    returns : face_i (P,), face_j (P,) int64, face_i < face_j, sorted lexicographically
    """
    triangles = np.asarray(triangles, dtype=np.float64)
    face_object = np.asarray(face_object, dtype=np.int64)
    face_static = _face_static_flags(face_object, object_static)
    face_count = triangles.shape[0]
    rows_per_pass = max(1, BRUTE_FORCE_PAIRS_PER_PASS // max(face_count, 1))
    found_i, found_j = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for first_row in range(0, face_count, rows_per_pass):
        rows = np.arange(first_row, min(first_row + rows_per_pass, face_count))
        face_i, face_j = np.repeat(rows, face_count), np.tile(np.arange(face_count), rows.size)
        keep = (face_i < face_j) & _candidate_filter(face_object, face_static, face_i, face_j)
        face_i, face_j = _pairs_within_exact_distance(triangles, face_i[keep], face_j[keep], radius)
        found_i.append(face_i)
        found_j.append(face_j)
    return _sorted_unique_pairs(np.concatenate(found_i), np.concatenate(found_j), max(face_count, 1))


class _FaceBounds(NamedTuple):
    """Conservative bounds of each face: centroid, radius of the sphere about it that holds
    the face, and the axis-aligned box."""

    centres: np.ndarray  # (F, 3)
    radii: np.ndarray  # (F,)
    lower: np.ndarray  # (F, 3)
    upper: np.ndarray  # (F, 3)


def _face_bounds(triangles):
    """_FaceBounds of (F, 3, 3) triangles (written out per vertex: reductions over an axis of
    length 3 are slow in numpy)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    centres = (a + b + c) / 3.0
    squared = [np.einsum("fj,fj->f", corner - centres, corner - centres) for corner in (a, b, c)]
    radii = np.sqrt(np.maximum(np.maximum(squared[0], squared[1]), squared[2]))
    return _FaceBounds(centres, radii, np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c))


def _size_classes(faces, radii):
    """Split faces into groups whose bounding radii lie within a factor of two of each other.

    faces : (m,) int, face indices; radii : (F,) float
    returns : list of (m_k,) int arrays, one per non-empty class
    """
    if faces.size == 0:
        return []
    face_radii = radii[faces]
    largest = face_radii.max()
    if largest <= 0.0:
        return [faces]
    ratio = np.maximum(face_radii / largest, 2.0**-SIZE_CLASS_DEPTH)
    classes = np.minimum(np.floor(-np.log2(ratio)).astype(np.int64), SIZE_CLASS_DEPTH)
    return [faces[classes == k] for k in np.unique(classes)]


class _ObjectFaces:
    """Each object's faces, its box, and its size classes with lazily built k-d trees."""

    def __init__(self, face_object, object_count, bounds):
        order = np.argsort(face_object, kind="stable")
        boundaries = np.searchsorted(face_object[order], np.arange(object_count + 1))
        self.faces = [order[boundaries[k] : boundaries[k + 1]] for k in range(object_count)]
        self.bounds = bounds
        self.lower, self.upper = self._object_boxes(order, boundaries)
        self._classes = {}

    def _object_boxes(self, order, boundaries):
        """(O, 3) lower and upper corners of each object's box; +-inf for objects without faces."""
        empty = (boundaries[1:] == boundaries[:-1])[:, None]
        starts = np.minimum(boundaries[:-1], max(len(order) - 1, 0))
        if len(order) == 0:
            return np.full((len(empty), 3), np.inf), np.full((len(empty), 3), -np.inf)
        lower = np.minimum.reduceat(self.bounds.lower[order], starts, axis=0)
        upper = np.maximum.reduceat(self.bounds.upper[order], starts, axis=0)
        return np.where(empty, np.inf, lower), np.where(empty, -np.inf, upper)

    def classes(self, object_index):
        """[(faces (m,) int, largest bounding radius, cKDTree of their centres)] of an object."""
        if object_index not in self._classes:
            self._classes[object_index] = [
                (faces, self.bounds.radii[faces].max(), cKDTree(self.bounds.centres[faces]))
                for faces in _size_classes(self.faces[object_index], self.bounds.radii)
            ]
        return self._classes[object_index]


def _object_pairs_in_reach(objects, object_static, radius):
    """Object pairs (o1 < o2), not both static, whose boxes grown by radius overlap."""
    first, second = np.triu_indices(objects.lower.shape[0], k=1)
    lower, upper = objects.lower, objects.upper
    box_gap = np.maximum(lower[first] - upper[second], lower[second] - upper[first]).max(axis=-1)
    slack_radius = radius * (1.0 + BOUND_RELATIVE_SLACK) + BOUND_ABSOLUTE_SLACK
    keep = (box_gap <= slack_radius) & ~(object_static[first] & object_static[second])
    return first[keep], second[keep]


def _object_pair_candidates(objects, object_1, object_2, radius):
    """Sphere-bound candidate face pairs between two objects, one tree query per class pair."""
    found_i, found_j = [], []
    for faces_1, largest_1, tree_1 in objects.classes(object_1):
        for faces_2, largest_2, tree_2 in objects.classes(object_2):
            bound = (radius + largest_1 + largest_2) * (1.0 + BOUND_RELATIVE_SLACK) + BOUND_ABSOLUTE_SLACK
            matrix = tree_1.sparse_distance_matrix(tree_2, bound, output_type="ndarray")
            found_i.append(faces_1[matrix["i"]])
            found_j.append(faces_2[matrix["j"]])
    return found_i, found_j


def _within_conservative_bounds(bounds, face_i, face_j, radius):
    """True where the bounding spheres and the boxes grown by radius both allow contact."""
    slack_radius = radius * (1.0 + BOUND_RELATIVE_SLACK) + BOUND_ABSOLUTE_SLACK
    sphere_reach = slack_radius + (bounds.radii[face_i] + bounds.radii[face_j]) * (1.0 + BOUND_RELATIVE_SLACK)
    centre_offsets = bounds.centres[face_i] - bounds.centres[face_j]
    centre_gap = np.sqrt(np.einsum("pj,pj->p", centre_offsets, centre_offsets))
    lower, upper = bounds.lower, bounds.upper
    box_gaps = np.maximum(lower[face_i] - upper[face_j], lower[face_j] - upper[face_i])
    box_gap = np.maximum(np.maximum(box_gaps[:, 0], box_gaps[:, 1]), box_gaps[:, 2])
    return (centre_gap <= sphere_reach) & (box_gap <= slack_radius)


def _candidate_pairs(triangles, face_object, object_static, radius):
    """Candidate face pairs of objects in reach of each other (superset of the answer)."""
    bounds = _face_bounds(triangles)
    objects = _ObjectFaces(face_object, object_static.shape[0], bounds)
    found_i, found_j = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for object_1, object_2 in zip(*_object_pairs_in_reach(objects, object_static, radius)):
        pair_i, pair_j = _object_pair_candidates(objects, int(object_1), int(object_2), radius)
        found_i += pair_i
        found_j += pair_j
    face_i, face_j = np.concatenate(found_i), np.concatenate(found_j)
    keep = _within_conservative_bounds(bounds, face_i, face_j, radius)
    return face_i[keep], face_j[keep]


def _object_static_flags(face_object, object_static):
    """(O,) bool static flags; all False (O = largest object index + 1) when None."""
    if object_static is not None:
        return np.asarray(object_static, dtype=bool)
    object_count = int(face_object.max()) + 1 if face_object.size else 0
    return np.zeros(object_count, dtype=bool)


def face_pairs_within_radius(triangles, face_object, radius, object_static=None):
    """All pairs of faces of different objects within `radius` of each other.

    Returns exactly the pairs of `brute_force_face_pairs`: faces of different objects, not
    both static, whose triangle–triangle distance (closest_points_triangles) is <= radius.
    Each unordered pair appears once with face_i < face_j, sorted lexicographically.

    triangles : (F, 3, 3) float, world coordinates
    face_object : (F,) int, the object of each face
    radius : float, the collision radius
    object_static : (O,) bool or None (None: no object is static)
    returns : face_i (P,), face_j (P,) int64
    """
    if not radius >= 0.0:
        raise ValueError(f"the collision radius must be a number >= 0, got {radius}")
    triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    face_object = np.asarray(face_object, dtype=np.int64)
    object_static = _object_static_flags(face_object, object_static)
    face_i, face_j = _candidate_pairs(triangles, face_object, object_static, float(radius))
    face_i, face_j = _sorted_unique_pairs(face_i, face_j, max(triangles.shape[0], 1))
    return _pairs_within_exact_distance(triangles, face_i, face_j, float(radius))
