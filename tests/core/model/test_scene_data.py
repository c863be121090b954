"""How trajectory files become the simulator's scenes: decimation, subdivision of static
meshes, and the crop of static faces out of reach (which must change no graph)."""

import dataclasses
import json

import numpy as np
import pytest

from fignetctl.core.model.scene_data import MIN_FACES, decimated_mesh, scene_from_trajectory, subdivided_mesh
from fignetctl.core.model.scene_graph import build_scene_graph
from fignetctl.core.model.simulator import SimulatorConfig
from tests.conftest import box_drop_file


def edge_lengths(vertices, faces):
    triangles = vertices[faces]
    return np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2)


def area(vertices, faces):
    triangles = vertices[faces]
    return (
        0.5
        * np.linalg.norm(
            np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1
        ).sum()
    )


def test_subdivision_bounds_edges_and_keeps_the_surface():
    vertices = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    new_vertices, new_faces = subdivided_mesh(vertices, faces, 0.5)
    assert edge_lengths(new_vertices, new_faces).max() <= 0.5
    assert np.isclose(area(new_vertices, new_faces), 400.0)
    assert np.allclose(new_vertices[:, 2], 0.0)
    normals = np.cross(*(new_vertices[new_faces[:, k]] - new_vertices[new_faces[:, 0]] for k in (1, 2)))
    assert (normals[:, 2] > 0).all()  # orientation kept


def test_static_meshes_are_subdivided_in_metres_and_dynamic_ones_are_not():
    data = box_drop_file(frames=4, height=0.8)
    data.trajectories["00000"].scales[0] = 2.0  # the floor is scaled: the bound is in metres
    scene = scene_from_trajectory(data, "00000", SimulatorConfig(max_static_edge=0.5))
    geometry = scene.geometry
    floor = geometry.face_object == 0
    assert edge_lengths(geometry.rest_vertices, geometry.faces[floor]).max() <= 0.5 + 1e-9
    assert floor.sum() > 1000
    assert (geometry.face_object == 1).sum() == 12
    untouched = scene_from_trajectory(data, "00000", SimulatorConfig(max_static_edge=None))
    assert (untouched.geometry.face_object == 0).sum() == 2


def test_only_dynamic_meshes_are_decimated():
    """Decimating an environment mesh tears holes in it; static meshes are kept whole."""
    import trimesh

    from fignetctl.core.trajectory import Mesh

    data = box_drop_file(frames=4, height=0.8)
    sphere = trimesh.creation.icosphere(subdivisions=3)  # 1280 faces
    data.meshes["box"] = data.meshes["floor"] = Mesh(
        np.asarray(sphere.vertices, np.float32), np.asarray(sphere.faces, np.int32)
    )
    geometry = scene_from_trajectory(data, "00000", SimulatorConfig(max_faces_per_object=100)).geometry
    assert (geometry.face_object == 0).sum() == 1280  # static: whole
    assert 0 < (geometry.face_object == 1).sum() <= 100  # dynamic: decimated


def support(vertices, directions):
    """How far a mesh reaches along each unit direction (its hull's support function), by
    brute force over the vertices: what decides where an object meets a floor or a wall."""
    return (np.asarray(vertices) @ directions.T).max(axis=0)


@pytest.fixture(scope="module")
def thin_walled_shapes(tmp_path_factory):
    """movi-b's mug (a hollow vessel with a handle) and gear (a thin toothed disc), and its
    sphere, from their subdivided meshes as make-dataset stores them."""
    from fignetctl.core import shapes

    cache = tmp_path_factory.mktemp("shapes")
    return {a.name: a for a in shapes.load_shapes("movi-b", names=["mug", "gear", "sphere"], cache_dir=cache)}


def test_train_refuses_to_decimate_below_what_rollout_and_evaluate_accept():
    """train's --max-faces declares its bound without importing torch; it must be the decimation's."""
    from fignetctl.stages import train

    field = {f.name: f for f in dataclasses.fields(train.Settings)}["max_faces"]
    assert field.metadata["low"] == MIN_FACES


def test_closest_decimation_keeps_where_thin_walled_shapes_reach(thin_walled_shapes):
    """Quadric decimation of the mug to 256 faces moved its reach by a third of its size; the
    'closest' decimation must keep every shape's reach, in 500 directions, within 1.5 % of its
    size, and the mug's volume within 2 % (trimesh's, independent of the decimation)."""
    import trimesh

    directions = np.random.default_rng(0).normal(size=(500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for name, asset in thin_walled_shapes.items():
        vertices, faces = np.asarray(asset.vertices, np.float64), np.asarray(asset.faces)
        size = np.ptp(vertices, axis=0).max()
        closest = decimated_mesh(vertices, faces, 256, "closest")
        assert len(closest[1]) <= 256 < len(faces)
        reach = np.abs(support(closest[0], directions) - support(vertices, directions)).max()
        assert reach <= 0.015 * size, (name, reach / size)
        if name == "mug":
            quadric = decimated_mesh(vertices, faces, 256, "quadric")
            assert np.abs(support(quadric[0], directions) - support(vertices, directions)).max() > 0.05 * size
            volumes = [trimesh.Trimesh(*mesh, process=False).volume for mesh in ((vertices, faces), closest)]
            assert volumes[1] == pytest.approx(volumes[0], rel=0.02)


def test_closest_decimation_is_the_quadric_one_where_that_keeps_the_surface(thin_walled_shapes):
    sphere = thin_walled_shapes["sphere"]
    closest = decimated_mesh(sphere.vertices, sphere.faces, 256, "closest")
    quadric = decimated_mesh(sphere.vertices, sphere.faces, 256, "quadric")
    for a, b in zip(closest, quadric):
        np.testing.assert_array_equal(a, b)


def test_closest_decimation_of_an_open_mesh_falls_back_to_quadric():
    """manifold3d takes only closed meshes; an open one (a hemisphere) is decimated as before."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    upper = sphere.faces[sphere.vertices[sphere.faces].mean(axis=1)[:, 2] > 0]
    vertices, faces = np.asarray(sphere.vertices), np.asarray(upper)
    closest = decimated_mesh(vertices, faces, 100, "closest")
    quadric = decimated_mesh(vertices, faces, 100, "quadric")
    assert 0 < len(closest[1]) <= 100
    for a, b in zip(closest, quadric):
        np.testing.assert_array_equal(a, b)


def test_model_files_without_the_decimation_field_keep_quadric_decimation():
    """Models trained before 'closest' saw quadric-decimated meshes and keep seeing them; new
    configurations decimate the closest way."""
    values = json.loads(SimulatorConfig().to_json())
    assert values.pop("decimation") == "closest"
    assert SimulatorConfig.from_json(json.dumps(values)).decimation == "quadric"
    with pytest.raises(ValueError, match="decimation"):
        SimulatorConfig(decimation="nearest")


def test_the_crop_of_static_faces_changes_no_graph_of_the_trajectory():
    data = box_drop_file(frames=40, height=1.2, dt=1 / 30)
    config = SimulatorConfig(max_static_edge=0.5)
    full = scene_from_trajectory(data, "00000", config)
    cropped = scene_from_trajectory(data, "00000", config, static_reach=1.0)
    assert (cropped.geometry.face_object == 0).sum() < (full.geometry.face_object == 0).sum() / 10
    contacts = 0
    for t in range(1, 39):
        graphs = [
            build_scene_graph(
                s.geometry, s.positions[t - 1 : t + 2], s.quaternions[t - 1 : t + 2], config.graph
            ).graph
            for s in (full, cropped)
        ]
        a, b = graphs
        assert a.node_features.shape == b.node_features.shape
        # same nodes up to the order of static vertices: compare sorted rows
        assert np.array_equal(
            np.sort(a.node_features.numpy(), axis=0), np.sort(b.node_features.numpy(), axis=0)
        )
        for name in a.edge_sets:
            fa, fb = a.edge_sets[name].features.numpy(), b.edge_sets[name].features.numpy()
            assert fa.shape == fb.shape
            assert np.array_equal(np.sort(fa, axis=0), np.sort(fb, axis=0)), name
        contacts += a.edge_sets["face_face"].num_edges > 0
    assert contacts > 5  # the box does reach the floor


def test_models_saved_before_the_setting_keep_their_meshes():
    values = dataclasses.asdict(SimulatorConfig())
    del values["max_static_edge"]
    import json

    assert SimulatorConfig.from_json(json.dumps(values)).max_static_edge is None
    del values["graph"]["max_vertex_offset"]
    assert SimulatorConfig.from_json(json.dumps(values)).graph.max_vertex_offset is None
    assert SimulatorConfig().graph.max_vertex_offset == 1.0
