"""cameras.npz round trip and checks; transforms.json export/import round trip."""

import json

import numpy as np
import pytest

from fignetctl.core.cameras import (
    Cameras,
    export_transforms_json,
    import_transforms_json,
    read_cameras,
    write_cameras,
)
from fignetctl.core.transforms import quat_to_matrix
from fignetctl.errors import FormatError


def random_cameras(n=5, seed=0):
    rng = np.random.default_rng(seed)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    c2w[:, :3, :3] = quat_to_matrix(quats)
    c2w[:, :3, 3] = rng.normal(size=(n, 3))
    K = np.tile(np.array([[100.0, 0, 40], [0, 110.0, 30], [0, 0, 1]]), (n, 1, 1))
    names = np.array([f"view_{i:03d}.png" for i in range(n)])
    points = rng.normal(size=(7, 3))
    colors = rng.integers(0, 255, size=(7, 3)).astype(np.uint8)
    return Cameras(names, K, c2w, 80, 60, points, colors)


def test_npz_round_trip(tmp_path):
    cameras = random_cameras()
    write_cameras(tmp_path / "cameras.npz", cameras)
    back = read_cameras(tmp_path / "cameras.npz")
    assert list(back.image_names) == list(cameras.image_names)
    np.testing.assert_array_equal(back.c2w, cameras.c2w)
    np.testing.assert_array_equal(back.K, cameras.K)
    np.testing.assert_array_equal(back.point_colors, cameras.point_colors)
    assert (back.width, back.height) == (80, 60)


def test_transforms_json_round_trip(tmp_path):
    cameras = random_cameras()
    export_transforms_json(tmp_path / "transforms.json", cameras)
    frame = json.loads((tmp_path / "transforms.json").read_text())["frames"][0]
    # OpenGL convention: the camera looks down its -z axis.
    np.testing.assert_allclose(np.array(frame["transform_matrix"])[:3, 2], -cameras.c2w[0, :3, 2])
    back = import_transforms_json(tmp_path / "transforms.json")
    np.testing.assert_allclose(back.c2w, cameras.c2w, atol=1e-12)
    np.testing.assert_allclose(back.K, cameras.K)
    assert list(back.image_names) == list(cameras.image_names)


def test_transforms_json_sparse_points_come_from_its_ply(tmp_path):
    import trimesh

    cameras = random_cameras()
    export_transforms_json(tmp_path / "transforms.json", cameras)
    cloud = trimesh.PointCloud(cameras.points, colors=np.c_[cameras.point_colors, np.full(7, 255)])
    cloud.export(tmp_path / "sparse_pc.ply")
    document = json.loads((tmp_path / "transforms.json").read_text())
    (tmp_path / "transforms.json").write_text(json.dumps({**document, "ply_file_path": "sparse_pc.ply"}))
    back = import_transforms_json(tmp_path / "transforms.json")
    np.testing.assert_allclose(back.points, cameras.points, atol=1e-6)
    np.testing.assert_array_equal(back.point_colors, cameras.point_colors)
    (tmp_path / "sparse_pc.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9")
    with pytest.raises(FormatError, match="ply_file_path 'sparse_pc.ply'"):
        import_transforms_json(tmp_path / "transforms.json")
    (tmp_path / "sparse_pc.ply").unlink()
    with pytest.raises(FormatError, match="sparse_pc.ply: no such PLY file"):
        import_transforms_json(tmp_path / "transforms.json")


def test_nerf_synthetic_camera_angle(tmp_path):
    document = {
        "camera_angle_x": 2 * np.arctan(0.5),
        "w": 100,
        "h": 80,
        "frames": [{"file_path": "./train/r_0", "transform_matrix": np.eye(4).tolist()}],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    cameras = import_transforms_json(tmp_path / "transforms.json")
    assert cameras.K[0, 0, 0] == pytest.approx(100.0)
    assert cameras.K[0, 1, 2] == pytest.approx(40.0)
    assert cameras.image_names[0] == "train/r_0"


@pytest.mark.parametrize(
    "lens, refused",
    [
        ({"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "camera_model": "OPENCV"}, False),  # zeros: pinhole
        ({"k1": -0.12}, True),
        ({"k1": 0.0, "p2": 0.001}, True),
        ({"camera_model": "OPENCV_FISHEYE"}, True),
    ],
)
def test_a_distorted_transforms_json_is_refused_never_read_as_pinhole(tmp_path, lens, refused):
    document = {
        "fl_x": 100.0,
        "cx": 50.0,
        "cy": 40.0,
        "w": 100,
        "h": 80,
        **lens,
        "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}],
    }
    (tmp_path / "transforms.json").write_text(json.dumps(document))
    if refused:
        with pytest.raises(FormatError, match="distorted .* undistort them first"):
            import_transforms_json(tmp_path / "transforms.json")
    else:
        assert import_transforms_json(tmp_path / "transforms.json").K[0, 0, 0] == 100.0


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda a: a.update(format=np.array("other")), "'format'"),
        (lambda a: a.update(format_version=np.array(9)), "format_version"),
        (lambda a: a.pop("K"), "missing field 'K'"),
        (lambda a: a["c2w"].__setitem__((1, 0, 3), np.nan), "NaN"),
        (lambda a: a["c2w"].__setitem__((0, 0, 0), 3.0), "not a rotation"),
        (lambda a: a.update(K=a["K"][:2]), "shape"),
    ],
)
def test_reader_refuses_damaged_files(tmp_path, damage, message):
    write_cameras(tmp_path / "good.npz", random_cameras())
    with np.load(tmp_path / "good.npz") as data:
        arrays = {key: data[key].copy() for key in data.files}
    damage(arrays)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(FormatError, match=message):
        read_cameras(tmp_path / "bad.npz")


def test_reader_refuses_truncated_and_random_bytes(tmp_path):
    write_cameras(tmp_path / "good.npz", random_cameras())
    data = (tmp_path / "good.npz").read_bytes()
    rng = np.random.default_rng(0)
    for i in range(30):
        cut = int(rng.integers(0, len(data)))
        (tmp_path / "bad.npz").write_bytes(data[:cut] if i % 2 else rng.bytes(cut + 1))
        with pytest.raises(FormatError):
            read_cameras(tmp_path / "bad.npz")
