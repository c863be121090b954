"""OBJ round trips: what write_obj and write_convex_parts_obj write reads back unchanged."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from fignetctl.core.obj import load_obj, read_obj, read_obj_groups, write_convex_parts_obj, write_obj
from fignetctl.errors import FignetError


def test_a_mesh_round_trips_through_write_obj(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.123456789)
    path = write_obj(tmp_path / "sphere.obj", mesh.vertices, mesh.faces)
    vertices, faces = read_obj(path)
    np.testing.assert_allclose(vertices, mesh.vertices, rtol=1e-8)
    np.testing.assert_array_equal(faces, mesh.faces)
    loaded = load_obj(path)
    np.testing.assert_allclose(loaded.vertices, mesh.vertices, rtol=1e-8)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_convex_parts_come_back_as_their_hulls_one_group_each(tmp_path):
    rng = np.random.default_rng(0)
    parts = [rng.normal(size=(40, 3)), rng.normal(size=(30, 3)) + 5.0]
    groups = read_obj_groups(write_convex_parts_obj(parts, tmp_path / "parts.obj"))
    assert len(groups) == 2
    for part, group in zip(parts, groups):
        hull = part[ConvexHull(part).vertices]
        assert sorted(map(tuple, np.round(group, 6))) == sorted(map(tuple, np.round(hull, 6)))


def test_polygons_are_fanned_and_negative_indices_resolved(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1 2/2 3/3 4/4\nf -4 -3 -2\n")
    _, faces = read_obj(path)
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3], [0, 1, 2]])
    path.write_text("v 0 0 0\n")
    with pytest.raises(FignetError, match="no triangles"):
        read_obj(path)
