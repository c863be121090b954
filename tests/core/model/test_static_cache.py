"""Graphs built with the static-geometry cache equal graphs built from every world vertex."""

import numpy as np
import pytest
import torch
import trimesh

from fignetctl.core.broadphase import brute_force_face_pairs
from fignetctl.core.model.graph import FACE_FACE
from fignetctl.core.model.scene_graph import (
    GraphConfig,
    build_scene_graph,
    collision_face_pairs,
    collision_face_pairs_from_poses,
    scene_geometry,
)
from fignetctl.core.transforms import random_quaternions


def ground_box_and_sphere():
    """A subdivided static ground (object 0), a static box with given motion (1), and a
    dynamic box (2) and sphere (3) near both."""
    ground = trimesh.creation.box(extents=[4.0, 4.0, 0.1]).subdivide().subdivide().subdivide()
    ground.vertices[:, 2] -= 0.05
    meshes = [
        ground,
        trimesh.creation.box(extents=[0.4, 0.4, 0.4]),
        trimesh.creation.box(),
        trimesh.creation.icosphere(1),
    ]
    geometry = scene_geometry(
        [(m.vertices, m.faces) for m in meshes], [1, 1, 0.5, 0.3], [True, True, False, False], np.ones((4, 3))
    )
    rng = np.random.default_rng(0)
    positions = np.zeros((5, 4, 3))
    positions[:, 1] = [0.6, 0.0, 0.2]
    positions[:, 2] = [0.0, 0.0, 0.3] + 0.01 * np.arange(5)[:, None]
    positions[:, 3] = [0.35, 0.1, 0.25] - 0.01 * np.arange(5)[:, None]
    quaternions = np.tile([1.0, 0, 0, 0], (5, 4, 1))
    quaternions[:, 2:] = random_quaternions(rng, 2)
    return geometry, positions, quaternions


def assert_same_graph(a, b):
    assert torch.equal(a.node_features, b.node_features)
    assert set(a.edge_sets) == set(b.edge_sets)
    for name, edge_set in a.edge_sets.items():
        for field in ("features", "senders", "receivers"):
            assert torch.equal(getattr(edge_set, field), getattr(b.edge_sets[name], field))


def test_cached_pairs_equal_the_uncached_and_brute_force_pairs_as_a_static_object_moves():
    geometry, positions, quaternions = ground_box_and_sphere()
    builds = []
    for frame in range(5):
        positions[frame, 1] += [0.0, 0.02 * frame, 0.0]  # the static box has given motion
        dynamic_now = geometry.world_vertices(positions[frame], quaternions[frame], geometry.dynamic_vertices)
        found = collision_face_pairs_from_poses(
            geometry, dynamic_now, positions[frame], quaternions[frame], 0.1
        )
        vertices = geometry.world_vertices(positions[frame], quaternions[frame])
        uncached = collision_face_pairs(geometry, vertices, 0.1)
        triangles = vertices[geometry.faces]
        expected = brute_force_face_pairs(triangles, geometry.face_object, 0.1, geometry.static)
        for pairs in (found, uncached):
            assert np.array_equal(pairs[0], expected[0]) and np.array_equal(pairs[1], expected[1])
        assert geometry.face_object[expected[0]].tolist().count(0) > 0
        builds.append(geometry.static_face_index.builds)
    assert builds == [2, 3, 4, 5, 6]  # the ground once, the moving box at every frame


def test_world_vertices_of_a_subset_are_the_rows_of_all_of_them():
    geometry, positions, quaternions = ground_box_and_sphere()
    rows = np.sort(np.random.default_rng(1).choice(len(geometry.rest_vertices), 50, replace=False))
    everything = geometry.world_vertices(positions[2], quaternions[2])
    assert np.array_equal(geometry.world_vertices(positions[2], quaternions[2], rows), everything[rows])


@pytest.mark.parametrize("surface_edges", [False, True])
def test_graph_is_the_same_with_a_cold_cache_a_warm_one_and_a_moved_static_object(surface_edges):
    geometry, positions, quaternions = ground_box_and_sphere()
    config = GraphConfig(collision_radius=0.15, surface_edges=surface_edges)
    for frame in (1, 2, 3):
        positions[frame + 1 :, 1] += [0.03, 0.0, 0.0]  # the static box moves between t and t+1
        history = positions[frame - 1 : frame + 2], quaternions[frame - 1 : frame + 2]
        warm = build_scene_graph(geometry, *history, config)
        fresh_geometry, _, _ = ground_box_and_sphere()
        cold = build_scene_graph(fresh_geometry, *history, config)
        assert_same_graph(warm.graph, cold.graph)
        assert np.array_equal(warm.node_vertex, cold.node_vertex)
        everything = np.stack([geometry.world_vertices(p, q) for p, q in zip(*history)])
        assert np.array_equal(warm.vertices, everything)
        assert np.array_equal(warm.dynamic_vertex_positions, everything[:, geometry.dynamic_vertices])
        assert warm.graph.edge_sets[FACE_FACE].num_edges > 0


def test_fignet_surface_edges_are_those_between_graph_nodes():
    geometry, positions, quaternions = ground_box_and_sphere()
    scene_graph = build_scene_graph(
        geometry, positions[:3], quaternions[:3], GraphConfig(0.15, surface_edges=True)
    )
    in_graph = np.zeros(len(geometry.rest_vertices), bool)
    in_graph[scene_graph.node_vertex[scene_graph.node_vertex >= 0]] = True
    expected = geometry.surface_edges[in_graph[geometry.surface_edges].all(axis=1)]
    edge_set = scene_graph.graph.edge_sets["node_node"]
    half = edge_set.num_edges // 2
    found = scene_graph.node_vertex[np.stack([edge_set.senders[:half], edge_set.receivers[:half]], axis=1)]
    assert np.array_equal(found, expected)
    assert (scene_graph.node_vertex[: scene_graph.num_dynamic_vertex_nodes] >= 0).all()
    assert geometry.static[geometry.vertex_object[expected]].any()  # edges of static nodes too


def test_a_scene_with_nothing_near_the_environment_has_no_static_nodes():
    geometry, positions, quaternions = ground_box_and_sphere()
    positions[:, 2:, 2] += 3.0
    scene_graph = build_scene_graph(geometry, positions[:3], quaternions[:3], GraphConfig(0.2))
    assert not geometry.static[
        geometry.vertex_object[scene_graph.node_vertex[scene_graph.node_vertex >= 0]]
    ].any()
    assert scene_graph.graph.num_nodes == len(geometry.dynamic_vertices) + 2
    assert scene_graph.node_positions.shape == (3, scene_graph.graph.num_nodes, 3)
