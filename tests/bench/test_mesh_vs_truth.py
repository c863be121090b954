"""benchmarks/mesh_vs_truth.py: an extract-mesh folder that holds the true mesh and the true
masks scores 1 per axis, no Chamfer distance and IoU 1; one scaled by 1.2 along x, in a frame
moved and scaled like capture-poses', scores 1.2 along x and fails the bar."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from tests.bench import load_benchmark


@pytest.fixture(scope="module")
def mesh_vs_truth():
    return load_benchmark("mesh_vs_truth")


def extraction_folder(folder, capture, frame, stretch=1.0):
    """An extract-mesh folder for the first prompted object: the true mesh moved into `frame`
    ((4, 4) similarity), stretched along x about its centre, and the true masks."""
    import cv2
    import trimesh

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.volume import Volume, write_volume

    obj = json.loads((capture / "prompts.json").read_text())["objects"][0]
    mesh = trimesh.load(capture / "ground_truth" / "objects" / f"{obj['name']}.obj", force="mesh")
    mesh.apply_transform(frame)
    centre = mesh.bounds.mean(axis=0)
    mesh.apply_translation(-centre)
    mesh.apply_scale([stretch, 1.0, 1.0])
    folder.mkdir(parents=True)
    mesh.export(folder / "object.obj")
    mesh.export(folder / "environment.obj")
    write_volume(folder / "volume.npz", Volume(centre - 1, centre + 1, centre, centre - 2, centre + 2))
    masks = np.load(capture / "ground_truth" / "masks.npz")["masks"]
    names = [str(n) for n in read_cameras(capture / "ground_truth" / "cameras.npz").image_names]
    (folder / "masks").mkdir()
    for point in obj["points"]:
        mask = masks[names.index(point["image"])] == obj["id"]
        cv2.imwrite(str(folder / "masks" / (Path(point["image"]).stem + ".png")), mask.astype(np.uint8) * 255)
    return obj["name"]


def moved_cameras(capture, path, frame):
    """The true cameras.npz moved into `frame` (a similarity: rotation, scale, translation)."""
    from fignetctl.core.cameras import read_cameras, write_cameras

    cameras = read_cameras(capture / "ground_truth" / "cameras.npz")
    scale = np.cbrt(np.linalg.det(frame[:3, :3]))
    c2w = cameras.c2w.copy()
    c2w[:, :3, :3] = frame[:3, :3] @ c2w[:, :3, :3] / scale
    c2w[:, :3, 3] = c2w[:, :3, 3] @ frame[:3, :3].T + frame[:3, 3]
    write_cameras(
        path,
        dataclasses.replace(
            cameras, c2w=c2w, points=np.zeros((0, 3)), point_colors=np.zeros((0, 3), np.uint8)
        ),
    )
    return path


def test_the_true_mesh_scores_one_and_a_stretched_one_fails_the_bar(mesh_vs_truth, small_capture, tmp_path):
    capture = small_capture
    from scipy.spatial.transform import Rotation

    frame = np.eye(4)
    frame[:3, :3] = 1.7 * Rotation.from_euler("z", 40, degrees=True).as_matrix()
    frame[:3, 3] = [0.3, -0.2, 0.05]
    cameras = moved_cameras(capture, tmp_path / "cameras.npz", frame)
    name = extraction_folder(tmp_path / "true", capture, frame)
    result = mesh_vs_truth.compare(capture, cameras, tmp_path / "true", name)
    np.testing.assert_allclose(result["size_ratio_xyz"], 1.0, atol=2e-3)
    assert result["chamfer_pct_of_size"] < 0.5 and result["meets_bar"]
    assert all(iou == 1.0 for iou in result["mask_iou"].values()) and len(result["mask_iou"]) >= 2
    if result["volume_ratio"] is not None:
        assert result["volume_ratio"] == pytest.approx(1.0, abs=2e-3)
    extraction_folder(tmp_path / "wide", capture, frame, stretch=1.2)
    wide = mesh_vs_truth.compare(capture, cameras, tmp_path / "wide", name)
    assert wide["size_ratio_xyz"][0] == pytest.approx(1.2, abs=5e-3) and not wide["meets_bar"]
    np.testing.assert_allclose(wide["size_ratio_xyz"][1:], 1.0, atol=2e-3)
