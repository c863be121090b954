"""`fignetctl capture-poses` through click: outputs, imports, and one-line errors for bad input."""

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.cameras import export_transforms_json, read_cameras, write_cameras
from tests.core.synthetic_views import render_views
from tests.rerun_reading import read_recording


def run(*args):
    return CliRunner().invoke(cli, ["capture-poses", *map(str, args)])


def assert_one_line_error(result, *fragments):
    assert result.exit_code != 0
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    message = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(message) == 1, result.output
    for fragment in fragments:
        assert fragment in message[0], message[0]


@pytest.fixture(scope="module")
def views(tmp_path_factory):
    folder = tmp_path_factory.mktemp("capture") / "images"
    return folder, render_views(folder, count=8, arc_deg=120)


def test_images_to_cameras_in_metres_z_up(views, tmp_path):
    folder, _truth = views
    output = tmp_path / "out" / "cameras.npz"
    result = run(
        "--images",
        folder,
        "--camera-height",
        0.5,
        "-o",
        output,
        "--export-transforms",
        tmp_path / "out" / "transforms.json",
        "--rerun",
        tmp_path / "out" / "poses.rrd",
    )
    assert result.exit_code == 0, result.output
    assert str(output) in result.stdout
    cameras = read_cameras(output)
    assert 7 <= len(cameras) <= 8
    assert cameras.centres[:, 2].mean() == pytest.approx(0.5, rel=1e-6)
    # The table is the support plane: most sparse points lie at z = 0, none far below it.
    assert np.median(np.abs(cameras.points[:, 2])) < 0.01
    assert np.percentile(cameras.points[:, 2], 2) > -0.02
    # Cameras look down at the table (OpenCV z forward has a negative world z).
    assert (cameras.c2w[:, 2, 2] < -0.3).all()
    frames = json.loads((tmp_path / "out" / "transforms.json").read_text())["frames"]
    assert frames[0]["file_path"].endswith(f"images/{cameras.image_names[0]}")
    recording = read_recording(tmp_path / "out" / "poses.rrd")  # one frustum and image per camera
    frusta = [f"world/cameras/{i:04d}" for i in range(len(cameras))]
    assert recording.entities_under("world/cameras") == sorted(frusta + [f + "/image" for f in frusta])
    for frustum in frusta:
        assert {"Pinhole:image_from_camera", "Transform3D:translation"} <= recording.components(frustum)
        assert recording.entities[frustum].static and recording.entities[frustum + "/image"].static
    assert recording.entities["world/points"].static and "Points3D:positions" in recording.components(
        "world/points"
    )
    assert recording.recording_id == str((tmp_path / "out").resolve())


def test_existing_output_needs_overwrite(views, tmp_path):
    (tmp_path / "cameras.npz").write_text("old")
    result = run("--images", views[0], "-o", tmp_path / "cameras.npz")
    assert_one_line_error(result, "--overwrite")
    assert (tmp_path / "cameras.npz").read_text() == "old"


def test_import_transforms_and_cameras_with_gravity_none(views, tmp_path):
    folder, truth = views
    export_transforms_json(tmp_path / "transforms.json", truth, image_prefix=f"{folder}/")
    result = run(
        "--import-transforms",
        tmp_path / "transforms.json",
        "--images",
        folder,
        "--gravity",
        "none",
        "-o",
        tmp_path / "a.npz",
    )
    assert result.exit_code == 0, result.output
    np.testing.assert_allclose(read_cameras(tmp_path / "a.npz").c2w, truth.c2w, atol=1e-12)
    write_cameras(tmp_path / "truth.npz", truth)
    # Re-aligning exact cameras without points: up from the cameras, scale from the true height.
    result = run(
        "--import-cameras",
        tmp_path / "truth.npz",
        "--images",
        folder,
        "--camera-height",
        0.5,
        "-o",
        tmp_path / "b.npz",
    )
    assert result.exit_code == 0, result.output
    assert "up from cameras" in result.output
    assert read_cameras(tmp_path / "b.npz").centres[:, 2].mean() == pytest.approx(0.5)


def test_video_to_cameras_and_images_folder(tmp_path):
    frames_dir = tmp_path / "render"
    truth = render_views(frames_dir, count=16, arc_deg=120)
    writer = cv2.VideoWriter(
        str(tmp_path / "orbit.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (truth.width, truth.height)
    )
    for name in truth.image_names:
        writer.write(cv2.imread(str(frames_dir / name)))
    writer.release()
    output = tmp_path / "out" / "cameras.npz"
    result = run("--video", tmp_path / "orbit.avi", "--every", 2, "-o", output)
    assert result.exit_code == 0, result.output
    cameras = read_cameras(output)
    assert 7 <= len(cameras) <= 8
    written = sorted(p.name for p in (tmp_path / "out" / "images").iterdir())
    assert set(map(str, cameras.image_names)) <= set(written) and len(written) == 8
    assert [p.name for p in (tmp_path / "out").iterdir() if p.name.startswith(".")] == []


# ----------------------------------------------------------------------------- bad input


def test_empty_folder(tmp_path):
    (tmp_path / "images").mkdir()
    result = run("--images", tmp_path / "images", "-o", tmp_path / "cameras.npz")
    assert_one_line_error(result, "holds no images")
    assert not (tmp_path / "cameras.npz").exists()


def test_unreadable_image(tmp_path, views):
    folder = tmp_path / "images"
    folder.mkdir()
    for name in views[1].image_names[:3]:
        (folder / name).write_bytes((views[0] / name).read_bytes())
    (folder / "broken.png").write_bytes(b"\x89PNG truncated")
    result = run("--images", folder, "-o", tmp_path / "cameras.npz")
    assert_one_line_error(result, "broken.png", "not a readable image")


def test_video_that_does_not_open(tmp_path):
    (tmp_path / "clip.mp4").write_bytes(b"not a video at all")
    result = run("--video", tmp_path / "clip.mp4", "-o", tmp_path / "out" / "cameras.npz")
    assert_one_line_error(result, "clip.mp4")
    assert not (tmp_path / "out" / "cameras.npz").exists()
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_blank_images_write_nothing(tmp_path):
    folder = tmp_path / "images"
    folder.mkdir()
    for index in range(5):
        cv2.imwrite(str(folder / f"blank_{index}.png"), np.full((60, 80, 3), 200, np.uint8))
    result = run(
        "--images", folder, "-o", tmp_path / "cameras.npz", "--export-transforms", tmp_path / "t.json"
    )
    assert_one_line_error(result, "only 0 of 5 images registered", "--matcher")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images"]


def test_cameras_that_do_not_match_the_images(tmp_path, views):
    _folder, truth = views
    write_cameras(tmp_path / "cameras.npz", truth)
    other = tmp_path / "other"
    other.mkdir()
    for name in truth.image_names:
        cv2.imwrite(str(other / name), np.zeros((50, 50, 3), np.uint8))
    result = run("--import-cameras", tmp_path / "cameras.npz", "--images", other, "-o", tmp_path / "out.npz")
    assert_one_line_error(result, "do not match")
    result = run(
        "--import-cameras", tmp_path / "cameras.npz", "--images", tmp_path, "-o", tmp_path / "out.npz"
    )
    assert_one_line_error(result, "is not in")
    assert not (tmp_path / "out.npz").exists()


def test_conflicting_inputs(tmp_path, views):
    result = run("--images", views[0], "--video", tmp_path / "v.mp4", "-o", tmp_path / "c.npz")
    assert_one_line_error(result, "give one input")
    result = run("-o", tmp_path / "c.npz")
    assert_one_line_error(result, "give one input")
    result = run(
        "--images", views[0], "--camera-height", 1, "--baseline", "a", "b", 1, "-o", tmp_path / "c.npz"
    )
    assert_one_line_error(result, "--baseline")


def test_help_has_an_example():
    result = CliRunner().invoke(cli, ["capture-poses", "--help"])
    assert result.exit_code == 0
    assert "fignetctl capture-poses --images" in result.output


def test_a_distorted_camera_model_writes_undistorted_images_and_keeps_colmap(views, tmp_path):
    from tests.core.synthetic_views import distort_image

    folder, truth = views
    distorted = tmp_path / "photos"
    distorted.mkdir()
    for name, K in zip(truth.image_names, truth.K):
        cv2.imwrite(str(distorted / name), distort_image(cv2.imread(str(folder / name)), K, 0.15))
    out = tmp_path / "out"
    args = ("--images", distorted, "--camera-model", "SIMPLE_RADIAL", "--keep-colmap", out / "colmap")
    result = run(*args, "-o", out / "cameras.npz", "--json", out / "poses.json")
    assert result.exit_code == 0, result.output
    cameras = read_cameras(out / "cameras.npz")
    undistorted = out / "images_undistorted"
    assert sorted(p.name for p in undistorted.iterdir()) == sorted(cameras.image_names)
    assert cv2.imread(str(undistorted / cameras.image_names[0])).shape[:2] == (cameras.height, cameras.width)
    assert (out / "colmap" / "sparse" / "0").is_dir() and (out / "colmap" / "points.ply").stat().st_size > 0
    assert json.loads((out / "poses.json").read_text())["images"] == str(undistorted)
    assert "undistorted images" in result.stderr
    # A second run beside the first finds the default folder taken: refused without --overwrite.
    assert_one_line_error(run(*args, "-o", out / "again.npz"), "--undistorted-dir", "--overwrite")
    assert not (out / "again.npz").exists()
    assert_one_line_error(
        run("--import-cameras", out / "cameras.npz", "--camera-model", "OPENCV", "-o", tmp_path / "c.npz"),
        "--camera-model",
    )
