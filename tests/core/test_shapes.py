"""Tests of the movi-b / movi-c shape library against trimesh, manifold3d and PyBullet itself."""

import logging

import numpy as np
import pytest
import trimesh

from fignetctl.core import shapes
from fignetctl.core.obj import read_obj_groups
from fignetctl.errors import FignetError

MILLIMETRE = 1e-3
CONVEX_SHAPES = ("cube", "cylinder", "sphere", "cone")


@pytest.fixture(scope="session")
def shape_cache(tmp_path_factory):
    """One shape cache for the session (the real one in ~/.cache is never touched)."""
    return tmp_path_factory.mktemp("shape-cache")


@pytest.fixture(scope="session")
def movi_b(shape_cache):
    """The 11 movi-b assets, built once."""
    return shapes.load_shapes("movi-b", cache_dir=shape_cache)


def mesh_of(asset):
    return trimesh.Trimesh(asset.vertices, asset.faces, process=False)


def union_volume(parts):
    """Volume of the manifold3d union of the parts' convex hulls (an independent union)."""
    import manifold3d

    hulls = [manifold3d.Manifold.hull_points(np.asarray(part, dtype=np.float64)) for part in parts]
    return manifold3d.Manifold.batch_boolean(hulls, manifold3d.OpType.Add).volume()


def pybullet_ray_offsets(asset, cache_dir, rays=300, seed=0):
    """(n,) float: trimesh hit distance minus PyBullet hit distance, near-normal rays only.

    PyBullet ray tests see the 1 mm collision margin around every convex part; rays that meet
    the mesh within 45 degrees of its normal would show ~1-1.4 mm if mesh = collision surface.
    """
    import pybullet

    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(rays, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    starts = rng.uniform(-0.3, 0.3, (rays, 3)) - 4 * directions
    client = pybullet.connect(pybullet.DIRECT)
    try:
        shape = shapes.create_pybullet_collision_shape(asset, physics_client_id=client, cache_dir=cache_dir)
        pybullet.createMultiBody(0.0, shape, physicsClientId=client)
        ends = starts + 8 * directions
        hits = pybullet.rayTestBatch(starts.tolist(), ends.tolist(), physicsClientId=client)
    finally:
        pybullet.disconnect(client)
    mesh = mesh_of(asset)
    locations, ray_index, triangle = mesh.ray.intersects_location(starts, directions, multiple_hits=False)
    cosine = np.abs(np.einsum("ij,ij->i", mesh.face_normals[triangle], directions[ray_index]))
    offsets = []
    for location, index, cos in zip(locations, ray_index, cosine):
        if cos > 0.7 and hits[index][0] >= 0:
            offsets.append(np.linalg.norm(location - starts[index]) - 8 * hits[index][2])
    return np.asarray(offsets)


# ----------------------------------------------------------------------------- movi-b


def test_movi_b_names_are_kubric_shapes_with_three_replacements():
    names = shapes.movi_b_names()
    assert len(names) == 11 and len(set(names)) == 11
    assert names[:8] == ["cube", "cylinder", "sphere", "cone", "torus", "gear", "torus_knot", "sponge"]
    assert names[8:] == ["bunny", "mug", "duck"]  # spot, teapot, suzanne


def test_movi_b_loads_all_shapes_with_declared_types(movi_b):
    assert [asset.name for asset in movi_b] == shapes.movi_b_names()
    for asset in movi_b:
        assert asset.vertices.dtype == np.float32 and asset.vertices.shape[1] == 3
        assert asset.faces.dtype == np.int32 and asset.faces.shape[1] == 3
        assert all(part.dtype == np.float32 and part.shape[1] == 3 for part in asset.convex_parts)
        assert asset.source


def test_movi_b_meshes_are_watertight_with_outward_faces(movi_b):
    for asset in movi_b:
        mesh = mesh_of(asset)
        assert mesh.is_watertight, asset.name
        assert mesh.is_winding_consistent, asset.name
        assert mesh.volume > 0, asset.name  # positive signed volume: counter-clockwise from outside
        # every closed piece faces outward too (touching V-HACD hulls stay separate pieces)
        assert all(piece.volume > 0 for piece in mesh.split(only_watertight=True)), asset.name


def test_movi_b_origin_at_centre_of_mass_and_largest_side_two(movi_b):
    for asset in movi_b:
        mesh = mesh_of(asset)
        assert np.abs(mesh.center_mass).max() < 1e-3 * 2.0, asset.name
        assert mesh.extents.max() == pytest.approx(2.0, abs=1e-5), asset.name


def test_movi_b_vertex_counts_in_range(movi_b):
    low, high = shapes.MOVI_B_VERTEX_RANGE
    for asset in movi_b:
        assert low <= len(asset.vertices) <= high, (asset.name, len(asset.vertices))


def test_convex_shapes_are_their_own_single_part(movi_b):
    for asset in movi_b:
        if asset.name in CONVEX_SHAPES:
            assert len(asset.convex_parts) == 1
            np.testing.assert_array_equal(asset.convex_parts[0], asset.vertices)
        else:
            assert len(asset.convex_parts) > 1, asset.name


@pytest.mark.filterwarnings("ignore:.*encountered in:RuntimeWarning")  # zero-area seam triangles
def test_movi_b_mesh_is_the_union_of_its_convex_parts(movi_b):
    for asset in movi_b:
        mesh = mesh_of(asset)
        assert shapes.surface_deviation(asset, samples=2000) < shapes.SURFACE_TOLERANCE, asset.name
        inside = trimesh.proximity.signed_distance(mesh, np.concatenate(asset.convex_parts))
        assert inside.min() > -shapes.SURFACE_TOLERANCE, asset.name  # no part pokes out of the mesh
        assert mesh.volume == pytest.approx(union_volume(asset.convex_parts), rel=1e-3), asset.name


def test_movi_b_resting_gap_is_pybullets_margin(movi_b, shape_cache):
    for asset in movi_b:
        gap = shapes.resting_gap(asset, cache_dir=shape_cache)
        assert abs(gap) < 5 * MILLIMETRE, (asset.name, gap)
        assert gap == pytest.approx(shapes.PYBULLET_COLLISION_MARGIN, abs=0.3 * MILLIMETRE), (asset.name, gap)


def test_movi_b_resting_gap_tilted_and_scaled(movi_b, shape_cache):
    for asset in movi_b:
        tilted = (0.9, 0.3, 0.2, 0.1)
        gap = shapes.resting_gap(asset, scale=1.4, quaternion_wxyz=tilted, cache_dir=shape_cache)
        assert abs(gap) < 5 * MILLIMETRE, (asset.name, gap)


def test_pybullet_rays_hit_the_mesh_plus_margin(movi_b, shape_cache):
    for asset in movi_b:
        offsets = pybullet_ray_offsets(asset, shape_cache)
        assert len(offsets) > 50, asset.name
        assert 0.5 * MILLIMETRE < np.median(offsets) < 1.5 * MILLIMETRE, asset.name
        assert np.percentile(offsets, 90) < 2 * MILLIMETRE, asset.name


def test_cached_load_returns_identical_arrays(movi_b, shape_cache, tmp_path):
    cached = shapes.load_shapes("movi-b", cache_dir=shape_cache)
    rebuilt = shapes.load_shapes("movi-b", names=["torus_knot", "duck"], cache_dir=tmp_path)
    by_name = {asset.name: asset for asset in cached}
    for first, second in zip(movi_b, cached):
        np.testing.assert_array_equal(first.vertices, second.vertices)
        np.testing.assert_array_equal(first.faces, second.faces)
        assert len(first.convex_parts) == len(second.convex_parts)
        for part, cached_part in zip(first.convex_parts, second.convex_parts):
            np.testing.assert_array_equal(part, cached_part)
        assert first.source == second.source
    for asset in rebuilt:  # a fresh build is deterministic
        np.testing.assert_array_equal(asset.vertices, by_name[asset.name].vertices)
    assert not [path for path in tmp_path.rglob("*") if ".tmp" in path.name]


def test_unreadable_cache_file_is_rebuilt(tmp_path):
    (first,) = shapes.load_shapes("movi-b", names=["cube"], cache_dir=tmp_path)
    (cache_file,) = tmp_path.glob("cube-*.npz")
    cache_file.write_bytes(b"not an npz")
    (again,) = shapes.load_shapes("movi-b", names=["cube"], cache_dir=tmp_path)
    np.testing.assert_array_equal(first.vertices, again.vertices)


def test_every_split_of_movi_b_has_all_shapes(shape_cache):
    assert len(shapes.load_shapes("movi-b", split="test", cache_dir=shape_cache)) == 11


def test_bad_input_raises_fignet_error(shape_cache, tmp_path):
    with pytest.raises(FignetError, match="preset"):
        shapes.load_shapes("movi-z", cache_dir=shape_cache)
    with pytest.raises(FignetError, match="split"):
        shapes.load_shapes("movi-b", split="validation", cache_dir=shape_cache)
    with pytest.raises(FignetError, match="teapot"):
        shapes.load_shapes("movi-b", names=["teapot"], cache_dir=shape_cache)
    flat = shapes.ShapeRecipe(
        name="flat",
        build=lambda: ([np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.0]])], None),
        source="test",
        input_files=(),
        largest_side=2.0,
        vertex_range=(0, 100),
    )
    with pytest.raises(FignetError, match="flat"):
        shapes.cached_asset(flat, tmp_path)
    with pytest.raises(FignetError, match="flat"):  # the failure is cached too
        shapes.cached_asset(flat, tmp_path)


# ----------------------------------------------------------------------------- movi-c


def test_movi_c_splits_are_disjoint_and_ten_percent():
    train, test, everything = (set(shapes.movi_c_names(split)) for split in ("train", "test", "all"))
    assert not train & test
    assert train | test == everything
    assert len(everything) == shapes.RANDOM_URDF_COUNT + len(shapes.MOVI_C_SCANS)
    assert 0.07 < len(test) / len(everything) < 0.13
    assert shapes.movi_c_names("test") == shapes.movi_c_names("test")  # deterministic
    assert all("/" not in name for name in everything)  # names are HDF5 group names


def test_movi_c_limit_loads_normalized_shapes(shape_cache):
    assets = shapes.load_shapes("movi-c", split="train", limit=3, cache_dir=shape_cache)
    assert [asset.name for asset in assets] == shapes.movi_c_names("train")[:3]
    for asset in assets:
        mesh = mesh_of(asset)
        assert mesh.is_watertight and mesh.volume > 0
        assert mesh.extents.max() == pytest.approx(1.0, abs=1e-5)
        assert np.abs(mesh.center_mass).max() < 1e-3
        assert shapes.surface_deviation(asset, samples=500) < shapes.SURFACE_TOLERANCE


def test_movi_c_scans_rest_on_the_floor(shape_cache):
    scans = shapes.load_shapes(
        "movi-c", split="all", names=["duck", "mug", "teddy", "lego"], cache_dir=shape_cache
    )
    for asset in scans:
        assert abs(shapes.resting_gap(asset, scale=2.0, cache_dir=shape_cache)) < 5 * MILLIMETRE, asset.name


def test_movi_c_bad_asset_is_skipped_with_a_warning(shape_cache, caplog):
    with caplog.at_level(logging.WARNING, logger="fignetctl.core.shapes"):
        assets = shapes.load_shapes("movi-c", split="all", names=["random_urdfs_168"], cache_dir=shape_cache)
    assert assets == []  # its OBJ file holds only NaN vertices
    assert "random_urdfs_168" in caplog.text


def test_read_obj_groups_one_array_per_group(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text(
        "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"
        "o b\nv 5 0 0\nv 6 0 0\nv 5 1 0\nv 5 0 1\nf -4 -3 -2\nf -4 -3 -1\nf -4 -2 -1\nf -3 -2 -1\n"
    )
    groups = read_obj_groups(path)
    assert len(groups) == 2
    np.testing.assert_array_equal(groups[1].min(axis=0), [5, 0, 0])


def test_collision_obj_is_named_by_its_contents(movi_b, tmp_path):
    cube, sphere = movi_b[0], movi_b[2]
    assert shapes.convex_parts_obj_path(cube, tmp_path) == shapes.convex_parts_obj_path(cube, tmp_path)
    renamed = shapes.ShapeAsset("x", sphere.vertices, sphere.faces, sphere.convex_parts, "")
    moved = shapes.ShapeAsset("x", sphere.vertices, sphere.faces, (sphere.convex_parts[0] + 1,), "")
    assert shapes.convex_parts_obj_path(renamed, tmp_path) != shapes.convex_parts_obj_path(moved, tmp_path)


@pytest.mark.slow
def test_movi_c_all_shapes_load_and_are_solid(tmp_path):
    assets = shapes.load_shapes("movi-c", split="all", cache_dir=tmp_path)
    assert len(assets) >= 0.99 * len(shapes.movi_c_names("all"))
    for asset in assets:
        mesh = mesh_of(asset)
        assert mesh.is_watertight and mesh.volume > 0, asset.name
        assert mesh.extents.max() == pytest.approx(1.0, abs=1e-5), asset.name
        assert len(asset.vertices) <= shapes.MOVI_C_VERTEX_RANGE[1], asset.name
