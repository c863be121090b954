"""Hard cases that must stay finite and accurate (DESIGN.md, "beyond the paper", item 2),
each against an exact answer or an independent reference. See docs/stability.md."""

import numpy as np
import pytest

from fignetctl.core.broadphase import brute_force_face_pairs, face_pairs_within_radius
from fignetctl.core.shape_matching import fit_rigid_transform
from fignetctl.core.triangles import closest_points_triangles
from fignetctl.errors import FignetError

pytestmark = pytest.mark.stability


# -- closest points between triangles --------------------------------------------------------


def _dense_samples(triangle, steps=48):
    """Points of a (3, 3) triangle on a barycentric grid (works for degenerate ones too)."""
    i, j = np.meshgrid(np.arange(steps + 1), np.arange(steps + 1), indexing="ij")
    keep = i + j <= steps
    u, v = i[keep] / steps, j[keep] / steps
    return triangle[0] + u[:, None] * (triangle[1] - triangle[0]) + v[:, None] * (triangle[2] - triangle[0])


def _sampled_distance(triangle_a, triangle_b):
    """Brute-force reference: the smallest distance between the two dense samplings."""
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(_dense_samples(triangle_b)).query(_dense_samples(triangle_a))
    return distance.min()


_UNIT = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
_DEGENERATE = {
    "point": np.array([[0.3, 0.2, 0.5]] * 3),
    "collinear": np.array([[-0.5, 0.3, 0.4], [0.5, 0.3, 0.6], [1.5, 0.3, 0.8]]),
    "repeated corner": np.array([[0.2, -0.5, 0.3], [0.2, -0.5, 0.3], [0.6, 1.2, -0.2]]),
    "sliver": np.array([[-0.4, 0.1, 0.3], [1.4, 0.1, 0.3], [0.5, 0.1 + 1e-9, 0.3 + 1e-9]]),
    "needle through": np.array([[0.2, 0.2, -1.0], [0.2, 0.2, 1.0], [0.2, 0.2 + 1e-12, 1.0]]),
}


@pytest.mark.parametrize("name", sorted(_DEGENERATE))
def test_degenerate_triangles_against_dense_sampling(name):
    """Exact distance is a lower bound of every sampled pair and at most one sampling cell
    (longest edge / 48 per triangle) below the best sampled pair."""
    rng = np.random.default_rng(0)
    degenerate = _DEGENERATE[name]
    for _ in range(6):
        rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        shift = rng.normal(size=3)
        a, b = degenerate @ rotation.T + shift, _UNIT @ rotation.T + shift
        for first, second in ((a, b), (b, a)):
            point_a, point_b, distance = closest_points_triangles(first[None], second[None])
            assert np.all(np.isfinite(point_a)) and np.all(np.isfinite(point_b))
            reference = _sampled_distance(first, second)
            cell = max(np.ptp(first, axis=0).max(), np.ptp(second, axis=0).max()) / 48
            assert distance[0] <= reference + 1e-12
            assert distance[0] >= reference - 2 * cell
            assert np.isclose(np.linalg.norm(point_a - point_b), distance[0], atol=1e-12)


def test_degenerate_against_degenerate_is_exact():
    """Two points, a point and a segment, two crossing segments: distances known exactly."""
    point = np.array([[1.0, 2.0, 3.0]] * 3)
    other_point = np.array([[4.0, 6.0, 3.0]] * 3)
    segment = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    crossing = np.array([[1.0, -1.0, 0.5], [1.0, 1.0, 0.5], [1.0, 0.0, 0.5]])
    _, _, distance = closest_points_triangles(
        np.stack([point, point, segment]), np.stack([other_point, segment, crossing])
    )
    np.testing.assert_allclose(distance, [5.0, np.hypot(2.0, 3.0), 0.5], rtol=0, atol=1e-12)


@pytest.mark.parametrize("gap", [0.0, 1e-9, 1e-3, 0.5])
def test_parallel_and_coplanar_triangles(gap):
    """Parallel overlapping faces at `gap`: distance exactly `gap`, both points in the overlap.
    Coplanar faces side by side with an in-plane gap: distance exactly `gap`."""
    rng = np.random.default_rng(1)
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    lower = _UNIT * 2.0
    upper = _UNIT * 2.0 + [0.5, 0.5, gap]
    beside = np.array([[-gap, 0.0, 0.0], [-gap - 1.0, 0.0, 0.0], [-gap, 1.0, 0.0]])
    for offset in (np.zeros(3), np.array([1e3, -2e3, 5e2])):
        a = np.stack([lower, lower]) @ rotation.T + offset
        b = np.stack([upper, beside]) @ rotation.T + offset
        point_a, point_b, distance = closest_points_triangles(a, b)
        assert np.all(np.isfinite(point_a)) and np.all(np.isfinite(point_b))
        tolerance = 1e-12 * (1 + np.abs(offset).max())
        np.testing.assert_allclose(distance, [gap, gap], rtol=0, atol=tolerance)


# -- broad phase: faces exactly at the collision radius --------------------------------------


@pytest.mark.parametrize("radius", [0.25, 0.1, 1.0 / 3.0])
def test_faces_exactly_at_the_radius(radius):
    """A face whose distance is the radius itself (in float64) is a pair (<= radius); one a
    float64 step farther is not. The broad phase agrees with the brute force in both."""
    floor = np.array([[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]])
    for height, expected in ((radius, 1), (np.nextafter(radius, 1.0) * (1 + 1e-15), 0)):
        above = floor + [0.0, 0.0, height]
        edge_on = np.array([[[0.0, 0.0, height], [0.0, 0.0, height + 1.0], [0.3, 0.0, height + 1.0]]])
        for other in (above, edge_on):
            triangles = np.concatenate([floor, other])
            face_object = np.array([0, 1])
            fast = face_pairs_within_radius(triangles, face_object, radius)
            slow = brute_force_face_pairs(triangles, face_object, radius)
            assert len(fast[0]) == len(slow[0]) == expected


# -- shape matching ---------------------------------------------------------------------------


def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _near_planar(rng, count, thickness):
    points = rng.normal(size=(count, 3))
    points[:, 2] *= thickness
    return points


@pytest.mark.parametrize("thickness", [0.0, 1e-9, 1e-4])
def test_shape_matching_on_near_planar_points_is_exact(thickness):
    rng = np.random.default_rng(2)
    for _ in range(20):
        source = _near_planar(rng, 12, thickness)
        rotation, translation = _rotation(rng), rng.normal(size=3) * 10
        target = source @ rotation.T + translation
        fitted_rotation, fitted_translation = fit_rigid_transform(source, target)
        assert np.isclose(np.linalg.det(fitted_rotation), 1.0, atol=1e-12)
        np.testing.assert_allclose(fitted_rotation, rotation, atol=1e-9)
        np.testing.assert_allclose(fitted_translation, translation, atol=1e-8)


@pytest.mark.parametrize("count", [1, 2, 5])
def test_shape_matching_on_collinear_points(count):
    """The rotation about the line is free; the fit is still a proper rotation, finite, and
    maps the source onto the target exactly."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        direction = rng.normal(size=3)
        source = np.linspace(-1, 1, count)[:, None] * direction + rng.normal(size=3)
        rotation, translation = _rotation(rng), rng.normal(size=3)
        target = source @ rotation.T + translation
        fitted_rotation, fitted_translation = fit_rigid_transform(source, target)
        assert np.all(np.isfinite(fitted_rotation)) and np.all(np.isfinite(fitted_translation))
        assert np.isclose(np.linalg.det(fitted_rotation), 1.0, atol=1e-12)
        np.testing.assert_allclose(fitted_rotation @ fitted_rotation.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(source @ fitted_rotation.T + fitted_translation, target, atol=1e-9)


def test_shape_matching_never_reflects():
    """A mirrored (planar and non-planar) target gets a proper rotation, never det −1."""
    rng = np.random.default_rng(4)
    for thickness in (1.0, 0.0):
        source = _near_planar(rng, 10, thickness)
        mirrored = source * [1.0, 1.0, -1.0] if thickness else source * [1.0, -1.0, 1.0]
        rotation, _ = fit_rigid_transform(source, mirrored)
        assert np.isclose(np.linalg.det(rotation), 1.0, atol=1e-12)
    rotation, translation = fit_rigid_transform(np.zeros((4, 3)), np.ones((4, 3)))
    assert np.isclose(np.linalg.det(rotation), 1.0) and np.allclose(translation, 1.0)


# -- graph features far from the origin, and tiny and huge objects ----------------------------


def _scene(box_size=1.0, gap=0.05, shift=(0.0, 0.0, 0.0)):
    """A box of edge `box_size` spinning `gap` above a static floor, poses for t−1, t, t+1."""
    import trimesh

    from fignetctl.core.model.scene_graph import scene_geometry

    box = trimesh.creation.box(extents=[box_size] * 3)
    floor = (
        np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], float) * max(box_size, 1.0),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    geometry = scene_geometry(
        [floor, (box.vertices, box.faces)],
        [1.0, 1.0],
        [True, False],
        np.array([[0, 0.5, 0.3], [1, 0.5, 0.5]]),
    )
    height = 0.5 * box_size + gap
    positions = np.array(
        [
            [[0, 0, 0], [0.01, 0, height + 0.02]],
            [[0, 0, 0], [0.02, 0, height]],
            [[0, 0, 0], [0.02, 0, height]],
        ]
    )
    angle = np.array([0.0, 0.05, 0.05])
    quaternions = np.zeros((3, 2, 4))
    quaternions[:, 0, 0] = 1.0
    quaternions[:, 1, 0], quaternions[:, 1, 3] = np.cos(angle / 2), np.sin(angle / 2)
    return geometry, positions + np.asarray(shift, float), quaternions


def _graph(geometry, positions, quaternions, radius):
    from fignetctl.core.model.scene_graph import GraphConfig, build_scene_graph

    return build_scene_graph(
        geometry, positions, quaternions, GraphConfig(collision_radius=radius, surface_edges=True)
    ).graph


@pytest.mark.parametrize("distance", [1e3, 1e4])
def test_graph_features_do_not_depend_on_where_the_scene_is(distance):
    """Every feature is relative (velocities, offsets, closest points, normals): the graph of
    a scene moved `distance` metres away equals the one at the origin, edge for edge. The
    poses are float64 here; the tolerance is float32's resolution of the features (1e-6 of
    their size) plus float64's of the distance (2.2e-16 * distance * a few)."""
    geometry, positions, quaternions = _scene()
    here = _graph(geometry, positions, quaternions, 0.1)
    there = _graph(geometry, positions + np.array([1.0, -0.6, 0.3]) * distance, quaternions, 0.1)
    assert here.node_features.shape == there.node_features.shape
    np.testing.assert_allclose(there.node_features.numpy(), here.node_features.numpy(), rtol=0, atol=1e-6)
    assert set(here.edge_sets) == set(there.edge_sets)
    for name, edges in here.edge_sets.items():
        moved = there.edge_sets[name]
        assert edges.features.shape == moved.features.shape and len(edges.features) > 0
        assert np.all(np.isfinite(moved.features.numpy()))
        assert np.array_equal(edges.senders.numpy(), moved.senders.numpy()), name
        assert np.array_equal(edges.receivers.numpy(), moved.receivers.numpy()), name
        tolerance = 2e-6 * max(1.0, float(edges.features.abs().max())) + 1e-15 * distance
        np.testing.assert_allclose(
            moved.features.numpy(), edges.features.numpy(), rtol=0, atol=tolerance, err_msg=name
        )


@pytest.mark.parametrize("box_size, gap", [(0.02, 0.002), (5.0, 0.05)])
def test_tiny_and_huge_objects_in_graph_building(box_size, gap):
    """A 2 cm box 2 mm above the floor and a 5 m box 5 cm above it: finite features, face–face
    edges exactly for the pairs the brute force finds within the radius, and the box's
    face-face distance feature equal to the gap (the floor is flat under it)."""
    from fignetctl.core.model.scene_graph import FACE_FACE

    geometry, positions, quaternions = _scene(box_size, gap)
    quaternions[:] = [1.0, 0.0, 0.0, 0.0]
    radius = 0.1
    graph = _graph(geometry, positions, quaternions, radius)
    assert np.all(np.isfinite(graph.node_features.numpy()))
    for edges in graph.edge_sets.values():
        assert np.all(np.isfinite(edges.features.numpy()))
    world = geometry.world_vertex_history(positions, quaternions)[1]
    triangles = world[geometry.faces]
    expected = brute_force_face_pairs(triangles, geometry.face_object, radius, geometry.static)
    face_face = graph.edge_sets[FACE_FACE]
    assert len(face_face.features) == 2 * len(expected[0]) > 0
    distances = face_face.features.numpy()[:, 3]
    assert np.isclose(distances.min(), gap, rtol=1e-5, atol=1e-7)


# -- extraction: empty masks, flat or empty density, no surface ------------------------------


def _settings(**changes):
    from fignetctl.core.mesh_extraction import ExtractionSettings

    return ExtractionSettings(**{"resolution": 24, "faces": 0, **changes})


@pytest.mark.parametrize("value", [0.0, 10.0, 50.0])
def test_density_that_is_empty_or_flat_below_the_threshold(value):
    from fignetctl.core.mesh_extraction import extract_object

    with pytest.raises(FignetError, match="no density above the threshold"):
        extract_object(
            lambda points: np.full(len(points), value), np.array([[0, 0, 0], [1, 1, 1.0]]), _settings()
        )


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_density_that_is_not_finite_gives_no_nan_vertices(bad):
    """NaN density counts as empty, +inf as solid: the mesh is a finite box (or nothing)."""
    from fignetctl.core.mesh_extraction import mesh_from_density

    def density(points):
        values = np.where(np.linalg.norm(points - 0.5, axis=1) < 0.3, 1000.0, 0.0)
        values[::7] = bad
        return values

    mesh = mesh_from_density(density, np.zeros(3), np.ones(3), _settings())
    assert len(mesh.faces) > 0 and np.all(np.isfinite(mesh.vertices))


def test_density_that_is_flat_above_the_threshold_fills_the_box():
    """Uniform solid density: marching cubes caps the box itself; the mesh is the box."""
    from fignetctl.core.mesh_extraction import mesh_from_density

    mesh = mesh_from_density(
        lambda points: np.full(len(points), 1000.0), np.zeros(3), np.ones(3), _settings()
    )
    assert np.all(np.isfinite(mesh.vertices))
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [1, 1, 1]], atol=1 / 23 + 1e-9)


def test_empty_masks_and_degenerate_mask_points():
    from fignetctl.core.mesh_extraction import View, object_box_from_points, object_box_from_views

    depth = np.ones((8, 8))
    views = [View(f"v{i}", np.eye(3), np.eye(4), depth, mask=np.zeros((8, 8), bool)) for i in range(2)]
    with pytest.raises(FignetError, match="empty"):
        object_box_from_views(views, _settings())
    with pytest.raises(FignetError):
        object_box_from_points([np.zeros((0, 3)), np.zeros((0, 3))], ["a", "b"], _settings())
    with pytest.raises(FignetError):  # every masked pixel unprojects to one point: no box
        object_box_from_points([np.ones((10, 3)), np.ones((10, 3))], ["a", "b"], _settings())


def test_marching_cubes_with_no_surface():
    from fignetctl.core.mesh_extraction import grid_axes, marching_cubes

    axes, _ = grid_axes(np.zeros(3), np.ones(3), 8)
    for values, threshold in (
        (np.zeros((8, 8, 8)), 1.0),
        (np.full((8, 8, 8), 5.0), 5.0),
        (np.ones((8, 8, 8)), np.nan),
        (np.ones((8, 8, 8)), 0.0),
    ):
        with pytest.raises(FignetError):
            marching_cubes(values, axes, threshold)
