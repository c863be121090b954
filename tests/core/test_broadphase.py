"""The broad phase returns exactly the brute-force face pairs, on scenes that stress it."""

import numpy as np
import pytest
import trimesh

from fignetctl.core import broadphase
from fignetctl.core.broadphase import (
    FaceGroup,
    StaticFaceIndex,
    brute_force_face_pairs,
    face_pairs_between_groups,
    face_pairs_within_radius,
)
from fignetctl.core.transforms import random_quaternions, transform_points
from fignetctl.core.triangles import closest_points_triangles


def posed_triangles(mesh, rng, centre):
    """(F, 3, 3) triangles of a trimesh at a random rotation about `centre`."""
    quaternion = random_quaternions(rng, 1)[0]
    vertices = transform_points(mesh.vertices, 1.0, np.asarray(centre, dtype=float), quaternion)
    return vertices[mesh.faces]


def floor_triangles(half_width=50.0, height=0.0):
    """(2, 3, 3) a square floor of two huge triangles at z = height."""
    corners = np.array([[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * half_width + [0, 0, height]
    return corners[[[0, 1, 2], [0, 2, 3]]]


def degenerate_faces(rng):
    """(3, 3, 3) a segment-like, a point-like and a sliver face near the origin."""
    a, b = rng.uniform(-0.3, 0.3, (2, 3)) + [0, 0, 0.3]
    return np.stack([[a, b, 0.5 * (a + b)], [a, a, a], [a, b, b + 1e-9]])


def random_scene(seed):
    """Objects of mixed face sizes close together on a floor; some objects static.

    returns : triangles (F, 3, 3), face_object (F,), object_static (O,)
    """
    rng = np.random.default_rng(seed)
    meshes = [
        trimesh.creation.icosphere(subdivisions=2, radius=0.15),
        trimesh.creation.icosphere(subdivisions=1, radius=0.3),
        trimesh.creation.box(extents=rng.uniform(0.2, 0.5, 3)),
        trimesh.creation.box(extents=[3.0, 3.0, 0.05]),
        trimesh.creation.cylinder(radius=0.2, height=0.4, sections=12),
        trimesh.creation.icosphere(subdivisions=1, radius=0.25),
    ]
    parts = [posed_triangles(mesh, rng, rng.uniform([-0.4, -0.4, 0.1], [0.4, 0.4, 0.5])) for mesh in meshes]
    parts += [degenerate_faces(rng), floor_triangles()]
    face_object = np.concatenate([np.full(len(part), k) for k, part in enumerate(parts)])
    object_static = np.zeros(len(parts), dtype=bool)
    object_static[[2, len(parts) - 1]] = True  # a box and the floor
    return np.concatenate(parts), face_object, object_static


def assert_same_pairs(found, expected):
    assert np.array_equal(found[0], expected[0]) and np.array_equal(found[1], expected[1])


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("radius", [0.0, 0.03, 0.15])
def test_matches_brute_force_on_random_scenes(seed, radius):
    triangles, face_object, object_static = random_scene(seed)
    expected = brute_force_face_pairs(triangles, face_object, radius, object_static)
    found = face_pairs_within_radius(triangles, face_object, radius, object_static)
    assert expected[0].size > 0
    assert_same_pairs(found, expected)


@pytest.mark.parametrize("dense_pairs", [0, 1 << 40], ids=["k-d trees", "all near pairs"])
@pytest.mark.parametrize("seed", [0, 1])
def test_both_candidate_searches_give_the_brute_force_pairs(monkeypatch, seed, dense_pairs):
    """Faces near each other's box are paired directly or through k-d trees (by their count):
    each way alone gives exactly the brute-force pairs, with and without margins."""
    monkeypatch.setattr(broadphase, "DENSE_CANDIDATE_PAIRS", dense_pairs)
    monkeypatch.setattr(broadphase, "DENSE_GROUP_FACES", 1 << 40)
    triangles, face_object, object_static = random_scene(seed)
    margins = np.random.default_rng(seed).uniform(0.0, 0.3, object_static.shape[0]) * ~object_static
    for radius, object_margins in ((0.15, None), (0.03, margins)):
        groups = [
            FaceGroup.from_triangles(np.flatnonzero(face_object == o), triangles[face_object == o])
            for o in range(len(object_static))
        ]
        found = face_pairs_between_groups(groups, object_static, radius, len(triangles), object_margins)
        expected = brute_force_face_pairs(triangles, face_object, radius, object_static, object_margins)
        assert expected[0].size > 0
        assert_same_pairs(found, expected)


@pytest.mark.parametrize("offset", [0.0, 1e3])
def test_the_separating_axis_drops_only_pairs_beyond_reach(offset):
    """The cheap test before the exact one never drops a pair within reach (touching, crossing,
    parallel at exactly the reach, far from the origin) and drops most pairs far beyond it."""
    rng = np.random.default_rng(11)
    first = rng.uniform(-0.1, 0.1, (4000, 3, 3))
    second = rng.uniform(-0.1, 0.1, (4000, 3, 3)) + rng.uniform(-0.6, 0.6, (4000, 1, 3))
    lower = np.array([[0.0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]])
    parallel = np.stack([lower, lower + [0, 0, 0.25]])  # 0.25 apart, the reach below
    first = np.concatenate([first, parallel[:1], lower[None]]) + offset
    piercing = np.array([[0.1, 0.1, -0.05], [0.1, 0.1, 0.05], [0.15, 0.1, 0.0]])
    second = np.concatenate([second, parallel[1:], piercing[None]]) + offset
    reach = np.full(len(first), 0.25)
    _, _, distance = closest_points_triangles(first, second)
    separated = broadphase._separated(first, second, reach)
    assert not separated[distance <= reach].any()
    assert distance[-2] == pytest.approx(0.25, abs=1e-9) and distance[-1] == 0.0
    assert separated[distance > 2 * reach].mean() > 0.5


@pytest.mark.parametrize("seed", [0, 1])
def test_per_object_margins_match_brute_force(seed):
    triangles, face_object, object_static = random_scene(seed)
    margins = np.random.default_rng(seed).uniform(0.0, 0.3, object_static.shape[0]) * ~object_static
    groups = [
        FaceGroup.from_triangles(np.flatnonzero(face_object == o), triangles[face_object == o])
        for o in range(len(object_static))
    ]
    found = face_pairs_between_groups(groups, object_static, 0.03, len(triangles), margins)
    expected = brute_force_face_pairs(triangles, face_object, 0.03, object_static, margins)
    plain = brute_force_face_pairs(triangles, face_object, 0.03, object_static)
    assert_same_pairs(found, expected)
    assert expected[0].size > plain[0].size  # the margins reach further


def test_closest_points_are_those_of_each_pair():
    triangles, face_object, object_static = random_scene(3)
    groups = [
        FaceGroup.from_triangles(np.flatnonzero(face_object == o), triangles[face_object == o])
        for o in range(len(object_static))
    ]
    pairs = face_pairs_between_groups(groups, object_static, 0.05, len(triangles))
    point_i, point_j, distance = closest_points_triangles(triangles[pairs.face_i], triangles[pairs.face_j])
    assert pairs.face_i.size > 10 and (pairs.distance <= 0.05).all()
    assert np.allclose(pairs.point_i, point_i, atol=1e-12) and np.allclose(pairs.point_j, point_j, atol=1e-12)
    assert np.allclose(pairs.distance, distance, atol=1e-12)


def test_pairs_are_ordered_unique_and_eligible():
    triangles, face_object, object_static = random_scene(2)
    face_i, face_j = face_pairs_within_radius(triangles, face_object, 0.1, object_static)
    assert np.all(face_i < face_j)
    keys = face_i * len(triangles) + face_j
    assert np.all(np.diff(keys) > 0)
    assert np.all(face_object[face_i] != face_object[face_j])
    assert not np.any(object_static[face_object[face_i]] & object_static[face_object[face_j]])
    _, _, distance = closest_points_triangles(triangles[face_i], triangles[face_j])
    assert np.all(distance <= 0.1)


def test_a_pair_at_exactly_the_radius_is_kept():
    triangles, face_object, object_static = random_scene(3)
    near_i, near_j = brute_force_face_pairs(triangles, face_object, 0.2, object_static)
    _, _, near_distance = closest_points_triangles(triangles[near_i], triangles[near_j])
    radius = float(np.sort(near_distance[near_distance > 0])[len(near_distance) // 3])
    below = float(np.nextafter(radius, 0.0))
    at_radius = face_pairs_within_radius(triangles, face_object, radius, object_static)
    just_below = face_pairs_within_radius(triangles, face_object, below, object_static)
    assert_same_pairs(at_radius, brute_force_face_pairs(triangles, face_object, radius, object_static))
    assert_same_pairs(just_below, brute_force_face_pairs(triangles, face_object, below, object_static))
    assert at_radius[0].size == just_below[0].size + np.count_nonzero(near_distance == radius)


def test_exact_gap_between_parallel_faces():
    lower = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    triangles = np.stack([lower, lower + [0, 0, 0.25]])
    face_object = np.array([0, 1])
    assert face_pairs_within_radius(triangles, face_object, 0.25)[0].tolist() == [0]
    assert face_pairs_within_radius(triangles, face_object, 0.2499999)[0].size == 0


def test_huge_floor_faces_meet_small_faces_resting_on_them():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    resting = sphere.vertices[sphere.faces] + [100.0, -200.0, 0.05]
    triangles = np.concatenate([floor_triangles(half_width=1000.0), resting])
    face_object = np.array([0, 0] + [1] * len(resting))
    found = face_pairs_within_radius(triangles, face_object, 0.01, np.array([True, False]))
    assert_same_pairs(found, brute_force_face_pairs(triangles, face_object, 0.01, np.array([True, False])))
    assert set(found[0].tolist()) <= {0, 1} and found[0].size > 0


def test_static_static_same_object_and_far_pairs_give_nothing():
    triangles, face_object, object_static = random_scene(4)
    all_static = np.ones_like(object_static)
    assert face_pairs_within_radius(triangles, face_object, 1.0, all_static)[0].size == 0
    assert face_pairs_within_radius(triangles, np.zeros_like(face_object), 1.0)[0].size == 0
    spread = triangles + 100.0 * face_object[:, None, None] * np.array([1.0, 0, 0])
    assert face_pairs_within_radius(spread, face_object, 1.0, object_static)[0].size == 0


def test_face_order_does_not_change_the_pairs():
    triangles, face_object, object_static = random_scene(5)
    order = np.random.default_rng(5).permutation(len(triangles))
    face_i, face_j = face_pairs_within_radius(triangles, face_object, 0.05, object_static)
    shuffled_i, shuffled_j = face_pairs_within_radius(
        triangles[order], face_object[order], 0.05, object_static
    )
    original = {tuple(sorted(pair)) for pair in zip(order[shuffled_i], order[shuffled_j])}
    assert original == set(zip(face_i.tolist(), face_j.tolist()))


def test_without_static_flags_and_with_no_faces():
    triangles, face_object, _ = random_scene(6)
    found = face_pairs_within_radius(triangles, face_object, 0.02)
    assert_same_pairs(found, brute_force_face_pairs(triangles, face_object, 0.02))
    empty = face_pairs_within_radius(np.zeros((0, 3, 3)), np.zeros(0, dtype=int), 0.1)
    assert empty[0].shape == (0,) and empty[1].shape == (0,)


def test_negative_or_nan_radius_is_refused():
    triangles, face_object, _ = random_scene(7)
    for radius in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="radius"):
            face_pairs_within_radius(triangles, face_object, radius)


def groups_of(triangles, face_object, object_static, static_index, pose_keys):
    """One FaceGroup per object; static ones from `static_index` under their pose key."""
    groups = []
    for obj in range(len(object_static)):
        faces = np.flatnonzero(face_object == obj)
        build = lambda faces=faces: FaceGroup.from_triangles(faces, triangles[faces])
        if object_static[obj]:
            groups.append(static_index.group(obj, pose_keys[obj], build))
        else:
            groups.append(build())
    return groups


def cached_pairs(triangles, face_object, object_static, radius, static_index, pose_keys):
    groups = groups_of(triangles, face_object, object_static, static_index, pose_keys)
    return face_pairs_between_groups(groups, object_static, radius, len(triangles))


@pytest.mark.parametrize("radius", [0.0, 0.05])
def test_cached_static_groups_give_the_brute_force_pairs_until_and_after_a_static_object_moves(radius):
    triangles, face_object, object_static = random_scene(8)
    index, keys = StaticFaceIndex(), {obj: b"rest" for obj in range(len(object_static))}
    expected = brute_force_face_pairs(triangles, face_object, radius, object_static)
    assert_same_pairs(cached_pairs(triangles, face_object, object_static, radius, index, keys), expected)
    builds = index.builds
    dynamic = ~object_static[face_object]
    rng = np.random.default_rng(8)
    for _ in range(3):  # dynamic objects move, static ones stay: nothing is rebuilt
        moved = triangles.copy()
        moved[dynamic] += rng.normal(0, 0.02, 3)
        found = cached_pairs(moved, face_object, object_static, radius, index, keys)
        assert_same_pairs(found, brute_force_face_pairs(moved, face_object, radius, object_static))
    assert index.builds == builds
    box = 2  # a static box: given motion changes its pose key, so its group is rebuilt
    moved = triangles.copy()
    moved[face_object == box] += [0.05, -0.03, 0.02]
    stale = cached_pairs(moved, face_object, object_static, radius, index, keys)
    keys[box] = b"moved"
    fresh = cached_pairs(moved, face_object, object_static, radius, index, keys)
    assert index.builds == builds + 1
    assert_same_pairs(fresh, brute_force_face_pairs(moved, face_object, radius, object_static))
    assert_same_pairs(stale, expected_with_static_from(triangles, moved, face_object, object_static, radius))


def expected_with_static_from(static_source, triangles, face_object, object_static, radius):
    """Brute-force pairs when static faces are read from `static_source` (a stale cache)."""
    mixed = np.where(object_static[face_object][:, None, None], static_source, triangles)
    return brute_force_face_pairs(mixed, face_object, radius, object_static)


def test_cached_pairs_at_exactly_the_radius():
    triangles, face_object, object_static = random_scene(9)
    near_i, near_j = brute_force_face_pairs(triangles, face_object, 0.2, object_static)
    _, _, near_distance = closest_points_triangles(triangles[near_i], triangles[near_j])
    radius = float(np.sort(near_distance[near_distance > 0])[len(near_distance) // 3])
    index, keys = StaticFaceIndex(), dict.fromkeys(range(len(object_static)), b"")
    for r in (radius, float(np.nextafter(radius, 0.0)), radius):
        found = cached_pairs(triangles, face_object, object_static, r, index, keys)
        assert_same_pairs(found, brute_force_face_pairs(triangles, face_object, r, object_static))
        assert_same_pairs(found, face_pairs_within_radius(triangles, face_object, r, object_static))
    assert index.builds == int(object_static.sum())


def test_a_large_static_mesh_far_from_moving_objects_gives_no_pairs():
    ground = trimesh.creation.box(extents=[20.0, 20.0, 0.1]).subdivide().subdivide()
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    parts = [ground.vertices[ground.faces], sphere.vertices[sphere.faces] + [0.0, 0.0, 1.0]]
    triangles = np.concatenate(parts)
    face_object = np.repeat([0, 1], [len(p) for p in parts])
    object_static = np.array([True, False])
    index = StaticFaceIndex()
    assert cached_pairs(triangles, face_object, object_static, 0.2, index, {0: b""})[0].size == 0
    assert cached_pairs(triangles, face_object, object_static, 0.96, index, {0: b""})[0].size > 0
    assert index.builds == 1
