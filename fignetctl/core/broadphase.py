"""Pairs of faces of different objects within a collision radius, without the all-pairs cost.

A face–face collision edge joins two faces of different objects whose triangle–triangle
distance is at most the collision radius. Static–static pairs never get an edge (the floor
and the environment do not collide with each other), so they are never even looked at.

The broad phase compares `FaceGroup`s, one per object: its faces' world triangles and their
conservative bounds. It finds candidates by bounds alone (with k-d trees over face centres
for large groups) and then keeps exactly the pairs that `closest_points_triangles` puts
within the radius:

1. Each face is bounded by a sphere about its centroid (radius r_i). Two faces can be within
   the radius R only if |c_i - c_j| <= R + r_i + r_j.
2. Only group pairs that are not both static and whose bounding boxes, grown by R, overlap
   are looked at: far-apart objects cost one box test, and static–static pairs nothing.
   Of such a pair, only the faces whose boxes, grown by R, meet the other group's box can
   be within R of it.
3. Where two groups are small and those faces make few pairs (two objects near each other,
   an object on a small floor), every pair of them gets the sphere test and an axis-aligned
   box test (boxes grown by R), on the whole table at once. Otherwise (an object beside a
   large static mesh) k-d trees find the candidates: faces differ wildly in size (a floor of 2 huge
   triangles beside small object faces), so each group's faces are split into size classes
   by powers of two of r_i, each with a k-d tree of centres. For each pair of classes
   (k, l) of the two groups, one tree query with the class bound R + max r_k + max r_l
   returns a superset, which the same two tests then thin out. A huge face is thus only
   tested with a bound of its own size, never inserted into a grid of small cells.
4. A pair that the line between its centroids separates by more than R is dropped; the
   exact distance decides the others, computed for each pair in the order (lower face
   index, higher) exactly as the brute force does. The bounds in 1–4 carry a small relative
   slack, so a pair at exactly the radius is never lost to rounding, and the result equals
   `brute_force_face_pairs` bit for bit.

Static geometry is usually at rest, so its groups need not be rebuilt: a `StaticFaceIndex`
keeps each static object's group (world triangles, bounds, trees) under a key of its pose
and rebuilds it only when the pose changes (given, kinematic motion). With the groups kept,
`face_pairs_between_groups` does no work per static face except for the faces the tree
queries return near a moving object, so a step's cost follows the moving geometry and its
contacts, not the size of the environment. `face_pairs_within_radius` is the simple entry
point that builds every group from all world triangles at each call (O(F)).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from fignetctl.core.triangles import closest_points_triangles

# Relative and absolute slack on the conservative bounds (not on the exact test).
BOUND_RELATIVE_SLACK = 1e-9
BOUND_ABSOLUTE_SLACK = 1e-12
# Slack, relative to the coordinates' size, on the separating-axis gaps that drop candidates
# before the exact test (far above their rounding).
SEPARATION_SLACK = 1e-9
# Faces smaller than 2**-SIZE_CLASS_DEPTH of the largest share the last size class.
SIZE_CLASS_DEPTH = 20
# Two groups of at most DENSE_GROUP_FACES faces each have their faces near the other's box
# paired directly (every pair bound-tested) when these make at most DENSE_CANDIDATE_PAIRS
# pairs; other group pairs are searched through k-d trees.
DENSE_GROUP_FACES = 4096
DENSE_CANDIDATE_PAIRS = 1 << 15
# Candidate pairs checked exactly per pass of the brute-force reference.
BRUTE_FORCE_PAIRS_PER_PASS = 1 << 20


def _face_static_flags(face_object, object_static):
    """(F,) bool: True for faces of static objects (all False when object_static is None)."""
    face_object = np.asarray(face_object, dtype=np.int64)
    if object_static is None:
        return np.zeros(face_object.shape[0], dtype=bool)
    return np.asarray(object_static, dtype=bool)[face_object]


def _sorted_unique_pairs(face_i, face_j, face_count):
    """Order each pair as (min, max), drop duplicates, sort lexicographically; also the index
    of each kept pair's first occurrence in the input."""
    low, high = np.minimum(face_i, face_j), np.maximum(face_i, face_j)
    keys, first = np.unique(low.astype(np.int64) * face_count + high, return_index=True)
    return keys // face_count, keys % face_count, first


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


def brute_force_face_pairs(triangles, face_object, radius, object_static=None, margins=None):
    """Reference for `face_pairs_within_radius`: the exact distance of every eligible pair.

    O(F²) work; for tests and benchmarks only.

    triangles : (F, 3, 3) float
    face_object : (F,) int, the object of each face
    radius : float
    object_static : (O,) bool or None
    margins : (O,) float or None: a pair of faces of objects a, b of which one is static is
        kept within radius + margins[a] + margins[b]
    returns : face_i (P,), face_j (P,) int64, face_i < face_j, sorted lexicographically
    """
    triangles = np.asarray(triangles, dtype=np.float64)
    face_object = np.asarray(face_object, dtype=np.int64)
    face_static = _face_static_flags(face_object, object_static)
    face_count = triangles.shape[0]
    margins = None if margins is None else np.asarray(margins, np.float64)
    rows_per_pass = max(1, BRUTE_FORCE_PAIRS_PER_PASS // max(face_count, 1))
    found_i, found_j = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for first_row in range(0, face_count, rows_per_pass):
        rows = np.arange(first_row, min(first_row + rows_per_pass, face_count))
        face_i, face_j = np.repeat(rows, face_count), np.tile(np.arange(face_count), rows.size)
        keep = (face_i < face_j) & _candidate_filter(face_object, face_static, face_i, face_j)
        face_i, face_j = face_i[keep], face_j[keep]
        reach = radius
        if margins is not None:
            with_static = face_static[face_i] | face_static[face_j]
            reach = radius + np.where(
                with_static, margins[face_object[face_i]] + margins[face_object[face_j]], 0.0
            )
        face_i, face_j = _pairs_within_exact_distance(triangles, face_i, face_j, reach)
        found_i.append(face_i)
        found_j.append(face_j)
    return _sorted_unique_pairs(np.concatenate(found_i), np.concatenate(found_j), max(face_count, 1))[:2]


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


class FaceGroup:
    """The faces of one object in world coordinates, with the bounds the broad phase tests.

    Building one costs O(m); its k-d trees are built on first use. A static object's group
    can be kept and reused for as long as the object does not move (`StaticFaceIndex`).

    faces : (m,) int, the global index of each face
    vertices : (n, 3) float64, world points
    corners : (m, 3) int, rows of `vertices` of each face's three corners
    """

    def __init__(self, faces, vertices, corners):
        self.faces = np.asarray(faces, dtype=np.int64)
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.corners = np.asarray(corners, dtype=np.int64).reshape(-1, 3)
        self.bounds = _face_bounds(self.triangles())
        empty = self.faces.size == 0
        self.lower = np.full(3, np.inf) if empty else self.bounds.lower.min(axis=0)
        self.upper = np.full(3, -np.inf) if empty else self.bounds.upper.max(axis=0)
        self._classes = None

    @classmethod
    def from_triangles(cls, faces, triangles):
        """faces (m,) int, triangles (m, 3, 3) float world coordinates -> FaceGroup."""
        triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        return cls(faces, triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3))

    def triangles(self, local=slice(None)):
        """(k, 3, 3) world triangles of the faces at the given local rows (all by default)."""
        return self.vertices[self.corners[local]]

    def classes(self):
        """[(local rows (m_k,) int, largest bounding radius, cKDTree of their centres)]."""
        if self._classes is None:
            self._classes = [
                (rows, self.bounds.radii[rows].max(), cKDTree(self.bounds.centres[rows]))
                for rows in _size_classes(np.arange(self.faces.size), self.bounds.radii)
            ]
        return self._classes


class StaticFaceIndex:
    """FaceGroups of static objects, each kept while its object's pose is unchanged.

    `group(object, pose_key, build)` returns the kept group when `pose_key` (any bytes that
    identify the pose, e.g. the position and quaternion) is the one it was built at, and
    otherwise calls `build()` and keeps the result. A static object at rest thus costs
    O(F_o) once; one with given (kinematic) motion is rebuilt each time its pose changes.
    `builds` counts the groups built.
    """

    def __init__(self):
        self._groups = {}
        self.builds = 0

    def group(self, object_index, pose_key, build) -> FaceGroup:
        kept = self._groups.get(object_index)
        if kept is not None and kept[0] == pose_key:
            return kept[1]
        group = build()
        self._groups[object_index] = (pose_key, group)
        self.builds += 1
        return group

    def kept(self, object_index, pose_key):
        """The kept group of an object if it was built at `pose_key`, else None."""
        kept = self._groups.get(object_index)
        return kept[1] if kept is not None and kept[0] == pose_key else None

    def clear(self):
        self._groups.clear()


def _slack(radius):
    return radius * (1.0 + BOUND_RELATIVE_SLACK) + BOUND_ABSOLUTE_SLACK


def _group_pairs_in_reach(groups, group_static, radius, margins):
    """(g1, g2, reach) for group pairs (g1 < g2), not both static, whose boxes grown by their
    reach overlap: radius + margins[g1] + margins[g2] for a pair with a static group, the
    radius for two moving groups."""
    if len(groups) < 2:
        return []
    lower = np.stack([group.lower for group in groups])
    upper = np.stack([group.upper for group in groups])
    first, second = np.triu_indices(len(groups), k=1)
    reach = radius + np.where(
        group_static[first] | group_static[second], margins[first] + margins[second], 0.0
    )
    box_gap = np.maximum(lower[first] - upper[second], lower[second] - upper[first]).max(axis=-1)
    keep = (box_gap <= _slack(reach)) & ~(group_static[first] & group_static[second])
    return list(zip(first[keep].tolist(), second[keep].tolist(), reach[keep].tolist()))


def _rows_near_box(group, lower, upper, radius):
    """Local rows of the faces of `group` whose boxes, grown by radius, meet the box
    [lower, upper] (another group's): no face outside it can be in reach of that group."""
    slack_radius = _slack(radius)
    near = (group.bounds.lower <= upper + slack_radius) & (group.bounds.upper >= lower - slack_radius)
    return np.flatnonzero(near.all(axis=1))


def _group_pair_candidates(group_1, group_2, radius):
    """Local rows (k,), (k,) of face pairs of two groups that the sphere and box bounds allow.

    Between two small groups (at most DENSE_GROUP_FACES faces each) only the faces near the
    other group's box take part, and where they make few pairs all of these are tested.
    Otherwise the size classes' k-d trees find the candidates, so a large static mesh costs
    nothing per face away from the other group."""
    if max(group_1.faces.size, group_2.faces.size) <= DENSE_GROUP_FACES:
        near_1 = _rows_near_box(group_1, group_2.lower, group_2.upper, radius)
        near_2 = _rows_near_box(group_2, group_1.lower, group_1.upper, radius)
        if near_1.size * near_2.size <= DENSE_CANDIDATE_PAIRS:
            return _all_pairs_within_bounds(group_1.bounds, group_2.bounds, near_1, near_2, radius)
    found_1, found_2 = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for rows_1, largest_1, tree_1 in group_1.classes():
        for rows_2, largest_2, tree_2 in group_2.classes():
            bound = (radius + largest_1 + largest_2) * (1.0 + BOUND_RELATIVE_SLACK) + BOUND_ABSOLUTE_SLACK
            matrix = tree_1.sparse_distance_matrix(tree_2, bound, output_type="ndarray")
            found_1.append(rows_1[matrix["i"]])
            found_2.append(rows_2[matrix["j"]])
    local_1, local_2 = np.concatenate(found_1), np.concatenate(found_2)
    keep = _within_conservative_bounds(group_1.bounds, group_2.bounds, local_1, local_2, radius)
    return local_1[keep], local_2[keep]


def _within_conservative_bounds(bounds_1, bounds_2, local_1, local_2, radius):
    """True where the bounding spheres and the boxes grown by radius both allow contact."""
    slack_radius = _slack(radius)
    sphere_reach = slack_radius + (bounds_1.radii[local_1] + bounds_2.radii[local_2]) * (
        1.0 + BOUND_RELATIVE_SLACK
    )
    centre_offsets = bounds_1.centres[local_1] - bounds_2.centres[local_2]
    centre_gap = np.sqrt(np.einsum("pj,pj->p", centre_offsets, centre_offsets))
    box_gaps = np.maximum(
        bounds_1.lower[local_1] - bounds_2.upper[local_2], bounds_2.lower[local_2] - bounds_1.upper[local_1]
    )
    box_gap = np.maximum(np.maximum(box_gaps[:, 0], box_gaps[:, 1]), box_gaps[:, 2])
    return (centre_gap <= sphere_reach) & (box_gap <= slack_radius)


def _all_pairs_within_bounds(bounds_1, bounds_2, rows_1, rows_2, radius):
    """The pairs of rows_1 × rows_2 that `_within_conservative_bounds` allows, found with the
    same arithmetic on the whole (n1, n2) table at once instead of on gathered pairs."""
    slack_radius = _slack(radius)
    radii_1, radii_2 = bounds_1.radii[rows_1], bounds_2.radii[rows_2]
    sphere_reach = slack_radius + (radii_1[:, None] + radii_2[None]) * (1.0 + BOUND_RELATIVE_SLACK)
    centres_1, centres_2 = bounds_1.centres[rows_1], bounds_2.centres[rows_2]
    lower_1, upper_1 = bounds_1.lower[rows_1], bounds_1.upper[rows_1]
    lower_2, upper_2 = bounds_2.lower[rows_2], bounds_2.upper[rows_2]
    squared = np.zeros((rows_1.size, rows_2.size))
    box_gap = np.full((rows_1.size, rows_2.size), -np.inf)
    for axis in range(3):
        offset = centres_1[:, axis, None] - centres_2[None, :, axis]
        squared += offset * offset
        box_gap = np.maximum(box_gap, lower_1[:, axis, None] - upper_2[None, :, axis])
        box_gap = np.maximum(box_gap, lower_2[None, :, axis] - upper_1[:, axis, None])
    first, second = np.nonzero((np.sqrt(squared) <= sphere_reach) & (box_gap <= slack_radius))
    return rows_1[first], rows_2[second]


def _ordered_candidates(group_1, group_2, local_1, local_2):
    """The candidate pairs as global (lower face, higher face), with their triangles in that
    order: the exact distance is computed in it, as the brute force does."""
    face_1, face_2 = group_1.faces[local_1], group_2.faces[local_2]
    swap = (face_1 > face_2)[:, None, None]
    triangles_1, triangles_2 = group_1.triangles(local_1), group_2.triangles(local_2)
    low, high = np.where(swap, triangles_2, triangles_1), np.where(swap, triangles_1, triangles_2)
    return np.minimum(face_1, face_2), np.maximum(face_1, face_2), low, high


def _separated(triangles_1, triangles_2, reach):
    """(n,) True where the line between two triangles' centroids separates them by more
    than `reach`.

    Projected onto an axis, two triangles are at least as far apart as the gap between their
    projections. The gap must exceed the reach by a slack larger than the rounding of the
    projections (SEPARATION_SLACK of the largest coordinate), so no pair within reach is ever
    dropped; the exact test decides all the others."""
    if len(reach) == 0:
        return np.zeros(0, bool)
    points_1 = triangles_1.transpose(1, 2, 0)  # (3 vertices, 3 coordinates, n)
    points_2 = triangles_2.transpose(1, 2, 0)
    axis = (points_2[0] + points_2[1] + points_2[2]) - (points_1[0] + points_1[1] + points_1[2])
    along_1 = [axis[0] * p[0] + axis[1] * p[1] + axis[2] * p[2] for p in points_1]
    along_2 = [axis[0] * p[0] + axis[1] * p[1] + axis[2] * p[2] for p in points_2]
    gap = np.minimum(np.minimum(*along_2[:2]), along_2[2]) - np.maximum(np.maximum(*along_1[:2]), along_1[2])
    length = np.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)  # gap is |axis| × the gap along it
    scale = max(np.abs(triangles_1).max(), np.abs(triangles_2).max())
    return gap > (_slack(reach) + SEPARATION_SLACK * scale) * length


class FacePairs(NamedTuple):
    """Face pairs in contact reach, with the closest points the exact test found.

    face_i, face_j : (P,) int64, face_i < face_j, sorted lexicographically
    point_i, point_j : (P, 3) float64, the closest points on face_i and on face_j
    distance : (P,) float64, their distance
    """

    face_i: np.ndarray
    face_j: np.ndarray
    point_i: np.ndarray
    point_j: np.ndarray
    distance: np.ndarray


def face_pairs_between_groups(groups, group_static, radius, face_count, margins=None) -> FacePairs:
    """All pairs of faces of different groups, not both static, within `radius` (plus the two
    groups' `margins`, when given), with their closest points.

    The work is one box test per group pair and, for groups in reach, k-d tree queries and
    bound tests that touch only faces near the other group: a static group far from every
    moving one costs nothing per face. The exact distances of all the candidates are then
    computed in one call.

    groups : list of FaceGroup, one per object
    group_static : (G,) bool
    radius : float >= 0
    face_count : int, more than every face index (orders the result)
    margins : (G,) float >= 0 or None: the faces of groups a and b, one of them static, pair
        within radius + margins[a] + margins[b] (speculative pairs with static geometry,
        GraphConfig.speculative); two moving groups pair within the radius
    returns : FacePairs (its first two fields are the pairs)
    """
    group_static = np.asarray(group_static, dtype=bool)
    margins = np.zeros(len(groups)) if margins is None else np.asarray(margins, np.float64)
    no_faces = np.zeros(0, dtype=np.int64)
    candidates = [(no_faces, no_faces, np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), np.zeros(0))]
    for first, second, reach in _group_pairs_in_reach(groups, group_static, radius, margins):
        local_1, local_2 = _group_pair_candidates(groups[first], groups[second], reach)
        face_low, face_high, low, high = _ordered_candidates(groups[first], groups[second], local_1, local_2)
        candidates.append((face_low, face_high, low, high, np.full(face_low.shape, reach)))
    face_low, face_high, low, high, reach = (np.concatenate(column) for column in zip(*candidates))
    apart = np.flatnonzero(~_separated(low, high, reach))
    point_low, point_high, distance = closest_points_triangles(low[apart], high[apart])
    near = np.flatnonzero(distance <= reach[apart])
    face_i, face_j, first = _sorted_unique_pairs(
        face_low[apart[near]], face_high[apart[near]], max(face_count, 1)
    )
    kept = near[first]
    return FacePairs(face_i, face_j, point_low[kept], point_high[kept], distance[kept])


def _object_static_flags(face_object, object_static):
    """(O,) bool static flags; all False (O = largest object index + 1) when None."""
    if object_static is not None:
        return np.asarray(object_static, dtype=bool)
    object_count = int(face_object.max()) + 1 if face_object.size else 0
    return np.zeros(object_count, dtype=bool)


def _faces_of_objects(face_object, object_count):
    """[(F_o,) int64 face indices of object o, ascending] for each object."""
    order = np.argsort(face_object, kind="stable")
    boundaries = np.searchsorted(face_object[order], np.arange(object_count + 1))
    return [order[boundaries[k] : boundaries[k + 1]] for k in range(object_count)]


def check_radius(radius):
    """The radius as a float; ValueError unless it is a number >= 0."""
    if not radius >= 0.0:
        raise ValueError(f"the collision radius must be a number >= 0, got {radius}")
    return float(radius)


def face_pairs_within_radius(triangles, face_object, radius, object_static=None):
    """All pairs of faces of different objects within `radius` of each other.

    Returns exactly the pairs of `brute_force_face_pairs`: faces of different objects, not
    both static, whose triangle–triangle distance (closest_points_triangles) is <= radius.
    Each unordered pair appears once with face_i < face_j, sorted lexicographically.

    This entry point takes every world triangle, so its cost grows with all faces; a caller
    that steps the same scene repeatedly keeps static objects' FaceGroups in a
    `StaticFaceIndex` and calls `face_pairs_between_groups` (see
    fignetctl.core.model.scene_graph.collision_face_pairs_from_poses).

    triangles : (F, 3, 3) float, world coordinates
    face_object : (F,) int, the object of each face
    radius : float, the collision radius
    object_static : (O,) bool or None (None: no object is static)
    returns : face_i (P,), face_j (P,) int64
    """
    radius = check_radius(radius)
    triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    face_object = np.asarray(face_object, dtype=np.int64)
    object_static = _object_static_flags(face_object, object_static)
    groups = [
        FaceGroup.from_triangles(faces, triangles[faces])
        for faces in _faces_of_objects(face_object, object_static.shape[0])
    ]
    return face_pairs_between_groups(groups, object_static, radius, triangles.shape[0])[:2]
