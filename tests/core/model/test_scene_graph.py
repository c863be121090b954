import numpy as np
import pytest
import torch
import trimesh

from fignetctl.core.model import scene_graph as scene_graph_module
from fignetctl.core.model.graph import FACE_FACE, NODE_NODE
from fignetctl.core.model.scene_graph import (
    GraphConfig,
    build_scene_graph,
    face_face_features,
    graph_signature_for,
    mesh_inertia_per_mass,
    scene_geometry,
    unique_undirected_edges,
)
from fignetctl.core.transforms import (
    quat_from_rotation_vector,
    quat_multiply,
    quat_to_matrix,
    random_quaternions,
)
from fignetctl.core.triangles import closest_points_triangles

FLOOR = (
    np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], float),
    np.array([[0, 1, 2], [0, 2, 3]]),
)


def _two_objects_over_floor():
    box, sphere = trimesh.creation.box(), trimesh.creation.icosphere(1)
    meshes = [FLOOR, (box.vertices, box.faces), (sphere.vertices, sphere.faces)]
    properties = [[0, 0.3, 0.5], [1.0, 0.5, 0.5], [2.0, 0.8, 0.7]]
    geometry = scene_geometry(meshes, [1, 1, 0.5], [True, False, False], properties)
    rng = np.random.default_rng(3)
    quaternions = np.stack([random_quaternions(rng, 3)] * 3)
    quaternions[:, 0] = [1, 0, 0, 0]
    positions = np.array([[0, 0, 0], [0.1, 0.0, 0.9], [0.2, 0.1, 1.85]], float)
    positions = np.stack([positions, positions + [0.01, 0, -0.02], positions + [0.02, 0, -0.04]])
    positions[:, 0] = 0.0
    return geometry, positions, quaternions


def _box_on_floor_under_sphere():
    """_two_objects_over_floor with the box just above the floor, the sphere down onto the box
    and the floor sliding over the step t -> t+1: floor-box and box-sphere contacts."""
    geometry, positions, quaternions = _two_objects_over_floor()
    positions[:, 1, 2] = 0.45
    positions[:, 2, 2] -= 0.85
    positions[2, 0] = [0.01, -0.02, 0.0]
    return geometry, positions, quaternions


def _face_face_closest_points(built, geometry):
    """The face-face edges' senders, receivers (E, 3) and their closest points and distance,
    found afresh per edge; asserts that floor-box and box-sphere pairs are both there."""
    edges = built.graph.edge_sets[FACE_FACE]
    now = built.node_positions[1]
    senders, receivers = edges.senders.numpy(), edges.receivers.numpy()
    objects = geometry.vertex_object[built.node_vertex[np.concatenate([senders[:, 0], receivers[:, 0]])]]
    assert {0, 1, 2} <= set(objects.tolist())
    return (senders, receivers, *closest_points_triangles(now[senders], now[receivers]))


def test_graph_has_every_node_and_collision_edges_only_near_contacts():
    geometry, positions, quaternions = _two_objects_over_floor()
    scene_graph = build_scene_graph(geometry, positions, quaternions, GraphConfig(collision_radius=0.2))
    dynamic_vertices = 8 + 42
    assert scene_graph.num_dynamic_vertex_nodes == dynamic_vertices
    assert (scene_graph.node_vertex[:dynamic_vertices] == geometry.dynamic_vertices).all()
    assert (scene_graph.node_vertex[-2:] == -1).all()
    face_face = scene_graph.graph.edge_sets[FACE_FACE]
    assert face_face.num_edges > 0 and face_face.num_edges % 2 == 0
    features = face_face.features.numpy()
    assert (features[:, 3] <= 0.2 + 1e-6).all()
    assert NODE_NODE not in scene_graph.graph.edge_sets


@pytest.mark.parametrize("static_receivers", [True, False])
def test_face_face_features_from_the_broad_phases_points_equal_those_computed_per_edge(
    static_receivers, monkeypatch
):
    """The edges reuse the closest points the broad phase found for each face pair, in both
    directions; computed afresh per directed edge they give the same graph."""
    geometry, positions, quaternions = _two_objects_over_floor()
    positions[:, 2, 2] -= 0.9  # the sphere down onto the box: dynamic–dynamic pairs too
    config = GraphConfig(collision_radius=0.2, static_receivers=static_receivers, contact_velocity=True)
    reused = build_scene_graph(geometry, positions, quaternions, config).graph.edge_sets[FACE_FACE]
    monkeypatch.setattr(
        scene_graph_module,
        "face_face_features",
        lambda senders, receivers, max_offset, closest, motion: face_face_features(
            senders, receivers, max_offset, None, motion
        ),
    )
    afresh = build_scene_graph(geometry, positions, quaternions, config).graph.edge_sets[FACE_FACE]
    assert reused.num_edges > 100
    assert torch.equal(reused.senders, afresh.senders) and torch.equal(reused.receivers, afresh.receivers)
    assert torch.allclose(reused.features, afresh.features, atol=1e-6)


def test_speculative_pairs_reach_as_far_as_an_object_moves_in_a_step():
    geometry, positions, quaternions = _two_objects_over_floor()
    quaternions[:, 1] = [1, 0, 0, 0]  # the unit box upright: its bottom face at z − 0.5
    positions[:, 2] = positions[1, 2] + [0.0, 0.0, 5.0]  # the sphere far above, at rest
    positions[:, 1, 2] = [1.1, 0.8, 0.5]  # the box falls 0.3 m per step; its bottom is 0.3 m up at t
    plain = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2))
    speculative = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2, speculative=True))
    assert plain.graph.edge_sets[FACE_FACE].num_edges == 0 and not plain.touching.any()
    gaps = speculative.graph.edge_sets[FACE_FACE].features.numpy()[:, 3]
    assert gaps.size and np.allclose(gaps.min(), 0.3) and (gaps <= 0.2 + 0.3 + 1e-6).all()
    assert list(speculative.touching) == [True, True, False]
    # an object at rest gets no margin: the same graph as without speculation
    positions[:, 1, 2] = 0.6
    a = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2)).graph
    b = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2, speculative=True)).graph
    assert a.edge_sets[FACE_FACE].num_edges > 0
    assert torch.equal(a.edge_sets[FACE_FACE].features, b.edge_sets[FACE_FACE].features)


def test_far_static_geometry_adds_no_nodes():
    geometry, positions, quaternions = _two_objects_over_floor()
    positions[:, 1:, 2] += 5.0  # lift both objects far above the floor
    scene_graph = build_scene_graph(geometry, positions, quaternions, GraphConfig(collision_radius=0.2))
    assert not np.isin(scene_graph.node_vertex, np.arange(4)).any()
    assert scene_graph.graph.num_nodes == 8 + 42 + 2


def test_fignet_star_graph_equals_fignet_graph_without_node_node_edges():
    geometry, positions, quaternions = _two_objects_over_floor()
    star = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2, surface_edges=False)).graph
    full = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2, surface_edges=True)).graph
    assert set(full.edge_sets) - set(star.edge_sets) == {NODE_NODE}
    assert torch.equal(full.node_features, star.node_features)
    for name, edge_set in star.edge_sets.items():
        assert torch.equal(edge_set.features, full.edge_sets[name].features)
        assert torch.equal(edge_set.senders, full.edge_sets[name].senders)
    node_node = full.edge_sets[NODE_NODE]
    dynamic_rows = 8 + 42
    between_dynamic = (node_node.senders < dynamic_rows) & (node_node.receivers < dynamic_rows)
    assert int(between_dynamic.sum()) == 2 * (18 + 120)  # a box's 18 edges and a 42-vertex icosphere's 120


def test_features_do_not_change_when_the_whole_scene_moves():
    geometry, positions, quaternions = _two_objects_over_floor()
    config = GraphConfig(0.2, surface_edges=True, contact_velocity=True)
    here = build_scene_graph(geometry, positions, quaternions, config).graph
    there = build_scene_graph(geometry, positions + [1000.0, -2000.0, 30.0], quaternions, config).graph
    torch.testing.assert_close(here.node_features, there.node_features, atol=2e-6, rtol=0)
    for name, edge_set in here.edge_sets.items():
        torch.testing.assert_close(edge_set.features, there.edge_sets[name].features, atol=2e-6, rtol=0)
        assert torch.equal(edge_set.senders, there.edge_sets[name].senders)


def test_face_face_features_do_not_depend_on_vertex_order():
    rng = np.random.default_rng(0)
    senders = rng.normal(size=(500, 3, 3))
    receivers = rng.normal(size=(500, 3, 3)) + [0.0, 0.0, 2.0]
    motion = (rng.normal(size=(500, 3, 3)), rng.normal(size=(500, 3, 3)))
    features, sender_order, receiver_order = face_face_features(senders, receivers, motion=motion)
    assert features.shape == (500, 38)
    for shift in (1, 2):  # cyclic permutations keep the orientation (and so the normal)
        rolled_features, rolled_sender, rolled_receiver = face_face_features(
            np.roll(senders, shift, axis=1),
            np.roll(receivers, shift, axis=1),
            motion=tuple(np.roll(m, shift, axis=1) for m in motion),
        )
        np.testing.assert_allclose(rolled_features, features, atol=1e-5)
        np.testing.assert_array_equal((rolled_sender - shift) % 3, sender_order)
        np.testing.assert_array_equal((rolled_receiver - shift) % 3, receiver_order)


def test_face_face_vertex_offsets_are_clamped_keeping_their_direction():
    """A small face 5 cm above a 40 m floor triangle: the floor's far vertices are shortened to
    the clamp; the closest-point vector, the distance, the normals and short offsets stay."""
    face = np.array([[[0.0, 0.0, 0.05], [0.1, 0.0, 0.05], [0.0, 0.1, 0.05]]])
    floor = np.array([[[-20.0, -20.0, 0.0], [20.0, -20.0, 0.0], [0.0, 20.0, 0.0]]])
    free, _, _ = face_face_features(face, floor)
    clamped, _, _ = face_face_features(face, floor, max_vertex_offset=1.0)
    # columns: closest-point vector 0:3, distance 3, sender offsets 4:13 and norms 13:16,
    # receiver offsets 16:25 and norms 25:28, normals 28:34
    receiver_offsets = clamped[0, 16:25].reshape(3, 3)
    np.testing.assert_allclose(np.linalg.norm(receiver_offsets, axis=1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(clamped[0, 25:28], 1.0, rtol=1e-6)
    free_offsets = free[0, 16:25].reshape(3, 3)
    assert (np.linalg.norm(free_offsets, axis=1) > 20).all()
    unit = free_offsets / np.linalg.norm(free_offsets, axis=1, keepdims=True)
    np.testing.assert_allclose(receiver_offsets, unit, atol=1e-6)
    np.testing.assert_array_equal(clamped[0, :16], free[0, :16])
    np.testing.assert_array_equal(clamped[0, 28:], free[0, 28:])


def test_face_face_features_of_degenerate_triangles_are_finite():
    point = np.zeros((1, 3, 3))
    segment = np.array([[[0, 0, 1.0], [1, 0, 1.0], [2, 0, 1.0]]])
    motion = (np.ones((1, 3, 3)), np.zeros((1, 3, 3)))
    features, _, _ = face_face_features(point, segment, motion=motion)
    assert np.isfinite(features).all()
    assert features[0, 3] == pytest.approx(1.0)
    np.testing.assert_array_equal(features[0, 34:], [-1.0, -1.0, -1.0, -1.0])  # closing at 1 per step


def test_signature_matches_built_graphs():
    geometry, positions, quaternions = _two_objects_over_floor()
    for surface_edges, contact_velocity in ((False, False), (True, False), (False, True)):
        config = GraphConfig(0.2, surface_edges, contact_velocity=contact_velocity)
        graph = build_scene_graph(geometry, positions, quaternions, config).graph
        signature = graph_signature_for(config)
        assert {n: e.features.shape[1] for n, e in graph.edge_sets.items()} == signature.edge_feature_sizes
        assert graph.node_features.shape[1] == signature.node_feature_size


def test_log_mass_feature_is_the_logarithm_of_each_dynamic_mass_and_zero_for_static_nodes():
    geometry, positions, quaternions = _two_objects_over_floor()
    positions[:, 1, 2] = 0.45  # the box on the floor, so floor vertices become nodes
    kg = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2))
    log = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2, log_mass=True))
    node_object = geometry.vertex_object[kg.node_vertex[kg.node_vertex >= 0]]
    assert geometry.static[node_object].any()  # static nodes are there to check
    mass_kg = kg.graph.node_features[: len(node_object), 6].numpy()
    mass_log = log.graph.node_features[: len(node_object), 6].numpy()
    np.testing.assert_array_equal(mass_kg, np.array([0.0, 1.0, 2.0], np.float32)[node_object])
    np.testing.assert_allclose(mass_log, np.log([1.0, 1.0, 2.0])[node_object], atol=1e-7)
    # everything else is the same graph
    others = [c for c in range(kg.graph.node_features.shape[1]) if c != 6]
    torch.testing.assert_close(kg.graph.node_features[:, others], log.graph.node_features[:, others])


@pytest.mark.parametrize("field", ["log_mass", "contact_velocity"])
def test_a_model_config_without_a_feature_field_reads_as_without_the_feature(field):
    """Model files older than the field: mass in kg, face-face edges without contact velocity."""
    import json

    from fignetctl.core.model.simulator import SimulatorConfig

    config = SimulatorConfig(graph=GraphConfig(0.2, **{field: True}))
    assert getattr(SimulatorConfig.from_json(config.to_json()).graph, field)
    values = json.loads(config.to_json())
    del values["graph"][field]
    assert getattr(SimulatorConfig.from_json(json.dumps(values)).graph, field) is False


def test_contact_velocity_is_the_rigid_velocity_of_one_closest_point_relative_to_the_other():
    """Against v + ω × (p − c) of each object at the closest points (found afresh per edge), and
    a static floor's given motion; the geometry columns stay as they were without it."""
    geometry, positions, quaternions = _box_on_floor_under_sphere()
    linear = np.array([[0, 0, 0], [0.01, -0.02, -0.03], [0.02, 0.01, -0.05]], float)
    angular = np.array([[0, 0, 0], [0.1, -0.2, 0.05], [-0.3, 0.1, 0.2]], float)
    config = GraphConfig(0.2, contact_velocity=True)
    built = build_scene_graph(geometry, positions, quaternions, config, velocities=(linear, angular))
    plain = build_scene_graph(
        geometry, positions, quaternions, GraphConfig(0.2), velocities=(linear, angular)
    ).graph.edge_sets[FACE_FACE]
    edges = built.graph.edge_sets[FACE_FACE]
    features = edges.features.numpy()
    torch.testing.assert_close(edges.features[:, :34], plain.features)
    senders, receivers, sender_point, receiver_point, distance = _face_face_closest_points(built, geometry)

    def motion_at(points, nodes):
        objects = geometry.vertex_object[built.node_vertex[nodes[:, 0]]]
        rigid = linear[objects] + np.cross(angular[objects], points - positions[1, objects])
        return np.where(geometry.static[objects][:, None], positions[2, 0] - positions[1, 0], rigid)

    closing = motion_at(receiver_point, receivers) - motion_at(sender_point, senders)
    np.testing.assert_allclose(features[:, 34:37], closing, atol=2e-6)
    apart = distance > 0  # touching or intersecting faces have no direction: 0
    assert apart.sum() > 10
    direction = (receiver_point[apart] - sender_point[apart]) / distance[apart, None]
    np.testing.assert_allclose(features[apart, 37], np.sum(closing[apart] * direction, axis=1), atol=2e-6)
    np.testing.assert_array_equal(features[~apart, 37], 0.0)


def test_contact_velocity_of_the_positions_state_is_the_closest_points_rigid_motion_from_t_minus_1():
    """Without velocities (the two-frame state) the columns are each closest point's rigid
    displacement t−1 -> t, found from the objects' two poses (the objects turn over the step),
    one relative to the other; a static floor's given motion t -> t+1."""
    geometry, positions, quaternions = _box_on_floor_under_sphere()
    turn = quat_from_rotation_vector(np.array([[0.0, 0.0, 0.0], [0.05, -0.1, 0.02], [-0.08, 0.03, 0.1]]))
    quaternions[0] = quat_multiply(turn, quaternions[1])
    built = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.2, contact_velocity=True))
    edges = built.graph.edge_sets[FACE_FACE]
    senders, receivers, sender_point, receiver_point, _ = _face_face_closest_points(built, geometry)

    def motion_at(points, nodes):
        objects = geometry.vertex_object[built.node_vertex[nodes[:, 0]]]
        body = np.einsum(
            "eji,ej->ei", quat_to_matrix(quaternions[1, objects]), points - positions[1, objects]
        )
        before = (
            np.einsum("eij,ej->ei", quat_to_matrix(quaternions[0, objects]), body) + positions[0, objects]
        )
        return np.where(geometry.static[objects][:, None], positions[2, 0] - positions[1, 0], points - before)

    closing = motion_at(receiver_point, receivers) - motion_at(sender_point, senders)
    assert np.abs(closing).max() > 0.02  # the turn moves the points by more than the tolerance
    np.testing.assert_allclose(edges.features.numpy()[:, 34:37], closing, atol=2e-6)


def test_surface_edges_are_each_mesh_edge_once_as_a_brute_force_count_finds_them():
    rng = np.random.default_rng(3)
    faces = np.concatenate([rng.integers(0, 40, (300, 3)), [[7, 7, 7], [0, 1, 2]]])
    expected = {tuple(sorted((int(a), int(b)))) for face in faces for a, b in zip(face, np.roll(face, -1))}
    edges = unique_undirected_edges(faces)
    assert [tuple(edge) for edge in edges.tolist()] == sorted(expected)
    assert unique_undirected_edges(np.zeros((0, 3), np.int64)).shape == (0, 2)


def test_mesh_inertia_per_mass_is_a_solids_about_its_origin_and_of_the_vertices_where_it_encloses_nothing():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    expected = np.diag([2.0**2 + 3.0**2, 1.0 + 3.0**2, 1.0 + 2.0**2]) / 12
    np.testing.assert_allclose(mesh_inertia_per_mass(box.vertices, box.faces), expected, atol=1e-12)
    # about the origin, not the centroid: the parallel-axis theorem (|d|² 1 − d dᵀ per unit mass)
    shift = np.array([0.3, -0.2, 0.5])
    shifted = mesh_inertia_per_mass(box.vertices + shift, box.faces)
    np.testing.assert_allclose(
        shifted, expected + shift @ shift * np.eye(3) - np.outer(shift, shift), atol=1e-12
    )
    # a turned solid's tensor turns with it, and its winding does not matter for a closed mesh
    matrix = quat_to_matrix(random_quaternions(np.random.default_rng(0), 1))[0]
    turned = mesh_inertia_per_mass(box.vertices @ matrix.T, box.faces[:, ::-1])
    np.testing.assert_allclose(turned, matrix @ expected @ matrix.T, atol=1e-12)
    # one open triangle: its three corners as point masses
    corners = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    np.testing.assert_allclose(mesh_inertia_per_mass(corners, [[0, 1, 2]]), (np.eye(3) * 3 - np.eye(3)) / 3)


def test_object_nodes_carry_their_inertia_in_the_world_frame_and_mesh_nodes_none():
    geometry, positions, quaternions = _two_objects_over_floor()
    plain = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.3))
    built = build_scene_graph(geometry, positions, quaternions, GraphConfig(0.3, inertia=True))
    assert graph_signature_for(GraphConfig(inertia=True)).node_feature_size == 21
    features = built.graph.node_features
    assert torch.equal(features[:, :12], plain.graph.node_features)
    object_nodes = built.node_vertex < 0
    assert not features[~object_nodes, 12:].any()
    box = trimesh.creation.box()
    rotation = quat_to_matrix(quaternions[1, 1])
    expected = rotation @ (np.eye(3) * 2 / 12) @ rotation.T  # a unit cube: (1 + 1) / 12 about every axis
    np.testing.assert_allclose(features[object_nodes][0, 12:].numpy().reshape(3, 3), expected, atol=1e-6)
    np.testing.assert_allclose(geometry.inertia_per_mass[1], mesh_inertia_per_mass(box.vertices, box.faces))
