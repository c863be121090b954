"""push_out_of_static: objects that a step puts into static meshes are moved back out, and
nothing else changes."""

import numpy as np
import pytest
import trimesh

from fignetctl.core.model.penetration import push_out_of_static
from fignetctl.core.model.scene_graph import scene_geometry
from fignetctl.core.transforms import random_quaternions

IDENTITY = [1.0, 0.0, 0.0, 0.0]


def _scene(static_mesh, dynamic_mesh):
    meshes = [(static_mesh.vertices, static_mesh.faces), (dynamic_mesh.vertices, dynamic_mesh.faces)]
    return scene_geometry(meshes, [1.0, 1.0], [True, False], [[0, 0.5, 0.5], [1, 0.5, 0.5]])


def _lowest(geometry, positions, quaternions):
    return geometry.world_vertices(positions, quaternions, geometry.object_vertices[1])[:, 2].min()


def test_a_box_that_falls_into_the_floor_ends_on_it_with_its_rotation_and_sideways_motion_kept():
    floor = trimesh.creation.box(
        extents=[20, 20, 0.2], transform=trimesh.transformations.translation_matrix([0, 0, -0.1])
    )
    geometry = _scene(floor, trimesh.creation.box(extents=[1, 1, 1]))
    rng = np.random.default_rng(0)
    quaternions = np.array([IDENTITY, random_quaternions(rng, 1)[0]])
    now = np.array([[0, 0, 0], [0.3, 0.2, 1.0]])
    predicted = np.array([[0, 0, 0], [0.5, 0.1, 0.4]])  # into the floor by ~0.4 m
    assert _lowest(geometry, predicted, quaternions) < -0.2
    corrected, shift = push_out_of_static(geometry, now, quaternions, predicted, quaternions)
    assert _lowest(geometry, corrected, quaternions) == pytest.approx(0.0, abs=1e-12)
    assert np.array_equal(corrected[1, :2], predicted[1, :2]) and corrected[1, 2] > predicted[1, 2]
    assert shift[1] == pytest.approx(corrected[1, 2] - predicted[1, 2]) and shift[0] == 0


def test_an_object_that_stays_clear_or_starts_inside_is_left_alone():
    floor = trimesh.creation.box(
        extents=[20, 20, 0.2], transform=trimesh.transformations.translation_matrix([0, 0, -0.1])
    )
    geometry = _scene(floor, trimesh.creation.box(extents=[1, 1, 1]))
    quaternions = np.array([IDENTITY, IDENTITY])
    clear = np.array([[0, 0, 0], [0, 0, 0.51]])
    assert np.array_equal(
        push_out_of_static(geometry, clear + [0, 0, 0.2], quaternions, clear, quaternions)[0], clear
    )
    inside = np.array([[0, 0, 0], [0, 0, 0.45]])  # 5 cm in already at t: not dragged through
    deeper = inside - [0, 0, 0.02]
    assert np.array_equal(push_out_of_static(geometry, inside, quaternions, deeper, quaternions)[0], deeper)


def test_a_fast_cube_does_not_tunnel_through_a_thin_plate():
    plate = trimesh.creation.box(extents=[2, 2, 0.01])
    geometry = _scene(plate, trimesh.creation.box(extents=[0.05, 0.05, 0.05]))
    quaternions = np.array([IDENTITY, IDENTITY])
    now = np.array([[0, 0, 0], [0.1, 0, 0.2]])
    through = np.array([[0, 0, 0], [0.12, 0, -0.3]])  # entirely below the plate after the step
    corrected, _ = push_out_of_static(geometry, now, quaternions, through, quaternions)
    assert corrected[1, 2] == pytest.approx(0.005 + 0.025, abs=1e-12)


def test_a_box_pushed_into_a_corner_comes_out_of_both_walls():
    floor = trimesh.creation.box(
        extents=[4, 4, 0.2], transform=trimesh.transformations.translation_matrix([0, 0, -0.1])
    )
    wall = trimesh.creation.box(
        extents=[0.2, 4, 4], transform=trimesh.transformations.translation_matrix([1.1, 0, 2])
    )
    geometry = _scene(trimesh.util.concatenate([floor, wall]), trimesh.creation.box(extents=[0.5, 0.5, 0.5]))
    quaternions = np.array([IDENTITY, IDENTITY])
    now = np.array([[0, 0, 0], [0.7, 0, 0.3]])
    predicted = np.array([[0, 0, 0], [0.9, 0, 0.15]])  # 0.15 m into the wall, 0.1 m into the floor
    corrected, _ = push_out_of_static(geometry, now, quaternions, predicted, quaternions)
    assert corrected[1] == pytest.approx([0.75, 0, 0.25], abs=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_random_drops_onto_a_sphere_end_outside_it_by_the_mesh_containment_test(seed):
    """Against trimesh's own inside test: after the correction no vertex of the dropped object
    is inside the static sphere (deeper than the tolerance)."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    geometry = _scene(sphere, trimesh.creation.box(extents=rng.uniform(0.1, 0.4, 3)))
    quaternions = np.array([IDENTITY, random_quaternions(rng, 1)[0]])
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    now = np.array([np.zeros(3), direction * 1.5])
    predicted = np.array([np.zeros(3), direction * rng.uniform(0.6, 1.0) + rng.normal(scale=0.05, size=3)])
    vertices = geometry.world_vertices(now, quaternions, geometry.object_vertices[1])
    assert not sphere.contains(vertices).any()
    corrected, shift = push_out_of_static(geometry, now, quaternions, predicted, quaternions)
    after = geometry.world_vertices(corrected, quaternions, geometry.object_vertices[1])
    assert shift[1] > 0
    depth = trimesh.proximity.signed_distance(sphere, after)  # trimesh: positive inside
    assert depth.max() <= 1e-9
