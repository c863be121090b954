"""Structure from motion (a small real pycolmap run), COLMAP import, frame picking from video."""

import math

import cv2
import numpy as np
import pytest

from fignetctl.core import sfm, video_frames
from fignetctl.core.world_alignment import AlignmentSettings, align, umeyama
from fignetctl.errors import FignetError, FormatError
from tests.core.synthetic_views import render_views


def rotation_error_deg(truth_c2w, rotation, estimated_c2w):
    relative = np.einsum("nji,jk,nkl->nil", truth_c2w[:, :3, :3], rotation, estimated_c2w[:, :3, :3])
    cosine = (np.trace(relative, axis1=1, axis2=2) - 1) / 2
    return np.degrees(np.arccos(np.clip(cosine, -1, 1)))


@pytest.fixture(scope="module")
def eight_views(tmp_path_factory):
    folder = tmp_path_factory.mktemp("views")
    return folder, render_views(folder, count=8, arc_deg=120)


# ----------------------------------------------------------------------------- inputs


def test_list_images_rejects_empty_unreadable_and_mixed_sizes(tmp_path):
    with pytest.raises(FignetError, match="holds no images"):
        sfm.list_images(tmp_path)
    with pytest.raises(FignetError, match="not a folder"):
        sfm.list_images(tmp_path / "missing")
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((20, 30, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((20, 40, 3), np.uint8))
    with pytest.raises(FignetError, match="different sizes"):
        sfm.list_images(tmp_path)
    (tmp_path / "b.png").write_bytes(b"not a png")
    with pytest.raises(FignetError, match="b.png: not a readable image"):
        sfm.list_images(tmp_path)
    (tmp_path / "b.png").unlink()
    assert sfm.list_images(tmp_path) == (["a.png"], 30, 20)


# ----------------------------------------------------------------------------- pycolmap


def test_sfm_recovers_the_synthetic_cameras(eight_views):
    folder, truth = eight_views
    cameras = sfm.run_sfm(folder)
    assert 7 <= len(cameras) <= 8  # pycolmap is not deterministic: a range
    assert len(cameras.points) > 100
    order = [list(truth.image_names).index(n) for n in cameras.image_names]
    scale, rotation, translation = umeyama(cameras.centres, truth.centres[order])
    error = np.linalg.norm(scale * cameras.centres @ rotation.T + translation - truth.centres[order], axis=1)
    assert error.max() < 0.01 * 1.6  # 1% of the ring's diameter
    assert rotation_error_deg(truth.c2w[order], rotation, cameras.c2w).max() < 1.0  # measured ~0.4°
    assert cameras.K[0, 0, 0] == pytest.approx(truth.K[0, 0, 0], rel=0.02)
    # Levelled and scaled: the table is z = 0 within 1°, the cameras 0.5 m above it.
    aligned, alignment = align(cameras, AlignmentSettings(camera_height=0.5))
    assert alignment.gravity_source == "plane"
    s, R, t = umeyama(aligned.centres, truth.centres[order])
    assert math.degrees(math.acos(min(1.0, (R @ [0, 0, 1.0])[2]))) < 1.0
    assert abs(s - 1) < 0.02 and abs(t[2]) < 0.01


def test_blank_images_do_not_register(tmp_path):
    for index in range(4):
        cv2.imwrite(str(tmp_path / f"blank_{index}.png"), np.full((60, 80, 3), 128, np.uint8))
    with pytest.raises(FignetError, match=r"only 0 of 4 images registered.*texture"):
        sfm.run_sfm(tmp_path)


def test_matcher_choice():
    assert sfm.SfmSettings().resolved_matcher(40) == "exhaustive"
    assert sfm.SfmSettings().resolved_matcher(500) == "sequential"
    assert sfm.SfmSettings(matcher="sequential").resolved_matcher(4) == "sequential"


# ----------------------------------------------------------------------------- COLMAP import


def write_colmap_text(folder):
    """A two-image COLMAP text model; camera a.png is turned 45° about y and shifted."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text("1 PINHOLE 320 240 300 310 160 120\n")
    half = math.radians(45) / 2
    (folder / "images.txt").write_text(
        f"1 {math.cos(half)} 0 {math.sin(half)} 0 0.1 0.2 0.3 1 a.png\n\n2 1 0 0 0 0 0 1 1 b.png\n\n"
    )
    (folder / "points3D.txt").write_text("1 0 0 1 255 0 0 0.5\n")


def test_import_colmap_text_model(tmp_path):
    write_colmap_text(tmp_path / "sparse")
    cameras = sfm.import_colmap(tmp_path / "sparse")
    assert list(cameras.image_names) == ["a.png", "b.png"]
    w2c = np.eye(4)
    c, s = math.cos(math.radians(45)), math.sin(math.radians(45))
    w2c[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    w2c[:3, 3] = [0.1, 0.2, 0.3]
    np.testing.assert_allclose(cameras.c2w[0], np.linalg.inv(w2c), atol=1e-6)
    np.testing.assert_allclose(cameras.centres[1], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(cameras.K[0], [[300, 0, 160], [0, 310, 120], [0, 0, 1]])
    np.testing.assert_allclose(cameras.points, [[0, 0, 1]])
    assert cameras.point_colors.tolist() == [[255, 0, 0]]


def test_import_colmap_rejects_other_folders(tmp_path):
    with pytest.raises(FormatError, match="no cameras.bin"):
        sfm.import_colmap(tmp_path)
    (tmp_path / "cameras.txt").write_text("garbage\n")
    (tmp_path / "images.txt").write_text("garbage\n")
    with pytest.raises(FormatError):
        sfm.import_colmap(tmp_path)


# ----------------------------------------------------------------------------- video frames


def textured_frame(rng, shift, size=(96, 128)):
    """A sharp random texture moved `shift` pixels to the right."""
    base = cv2.resize(rng.random((24, 32)), (size[1] + 64, size[0]), interpolation=cv2.INTER_NEAREST)
    image = (base[:, shift : shift + size[1]] * 255).astype(np.uint8)
    return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)


def write_video(path, frames, fps=10):
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (frames[0].shape[1], frames[0].shape[0])
    )
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()


def test_pick_frames_skips_blurred_frames(tmp_path):
    texture_rng = np.random.default_rng(1)
    frames, blurred = [], set()
    base_texture = textured_frame(texture_rng, 0)
    for index in range(30):
        frame = np.roll(base_texture, index, axis=1)
        if index % 5 in (0, 1) or index in (12, 13):  # the nominal picks and more are blurred
            frame = cv2.GaussianBlur(frame, (0, 0), 3)
            blurred.add(index)
        frames.append(frame)
    write_video(tmp_path / "video.avi", frames)
    picks = video_frames.pick_frames(tmp_path / "video.avi", tmp_path / "frames", every=5)
    assert len(picks) == 6  # one per window of 5 frames
    assert not blurred & {p.index for p in picks}
    assert sorted(p.name for p in picks) == sorted(f.name for f in (tmp_path / "frames").iterdir())
    assert cv2.imread(str(tmp_path / "frames" / picks[0].name)).shape == (96, 128, 3)


def test_drop_blurred_windows():
    picks = [video_frames.PickedFrame(i, s, None) for i, s in enumerate([100, 110, 20, 105, 95])]
    assert [p.index for p in video_frames.drop_blurred(picks, 0.5, 2)] == [0, 1, 3, 4]


def test_video_that_does_not_open(tmp_path):
    (tmp_path / "broken.mp4").write_bytes(b"this is not a video")
    with pytest.raises(FignetError, match="cannot open|no readable frames"):
        video_frames.pick_frames(tmp_path / "broken.mp4", tmp_path / "frames")
    with pytest.raises(FignetError, match="no such video"):
        video_frames.pick_frames(tmp_path / "missing.mp4", tmp_path / "frames")


def test_staged_folder_replaces_only_on_commit_and_only_what_it_owns(tmp_path):
    from fignetctl.core.atomic import StagedDirectory

    target = tmp_path / "images"
    target.mkdir()
    (target / "frame_1.png").write_text("old")
    with StagedDirectory(target, ("frame_*.png",)) as staged:
        (staged.path / "frame_2.png").write_text("new")
    assert [p.name for p in target.iterdir()] == ["frame_1.png"]
    with StagedDirectory(target, ("frame_*.png",)) as staged:
        (staged.path / "frame_2.png").write_text("new")
        staged.commit()
    assert [p.name for p in target.iterdir()] == ["frame_2.png"]
    assert [p.name for p in tmp_path.iterdir()] == ["images"]
    (target / "notes.txt").write_text("mine")
    with pytest.raises(FignetError, match="holds notes.txt, which this command does not write"):
        StagedDirectory(target, ("frame_*.png",))
    assert sorted(p.name for p in target.iterdir()) == ["frame_2.png", "notes.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["images"]


def test_a_colmap_camera_with_distortion_is_refused_and_one_without_is_pinhole():
    pycolmap = pytest.importorskip("pycolmap")
    radial = pycolmap.Camera(model="SIMPLE_RADIAL", width=64, height=48, params=[50.0, 32.0, 24.0, -0.08])
    with pytest.raises(FormatError, match="SIMPLE_RADIAL with distortion .* undistort the images first"):
        sfm._pinhole_K(radial)
    flat = pycolmap.Camera(model="SIMPLE_RADIAL", width=64, height=48, params=[50.0, 32.0, 24.0, 0.0])
    np.testing.assert_allclose(sfm._pinhole_K(flat), [[50, 0, 32], [0, 50, 24], [0, 0, 1]])


def test_a_distorted_capture_gives_the_pinhole_poses_and_undistorted_images(eight_views, tmp_path):
    """Views recorded through radial distortion k1 = 0.15: SIMPLE_RADIAL recovers the poses as
    well as a pinhole capture does, and the undistorted images match the pinhole renders."""
    from tests.core.synthetic_views import distort_image, resample

    folder, truth = eight_views
    distorted, undistorted, kept = tmp_path / "distorted", tmp_path / "undistorted", tmp_path / "colmap"
    for path in (distorted, undistorted, kept):
        path.mkdir()
    for name, K in zip(truth.image_names, truth.K):
        cv2.imwrite(str(distorted / name), distort_image(cv2.imread(str(folder / name)), K, 0.15))
    settings = sfm.SfmSettings(camera_model="SIMPLE_RADIAL")
    cameras = sfm.run_sfm(distorted, settings=settings, undistorted_dir=undistorted, keep_dir=kept)
    assert 7 <= len(cameras) <= 8
    order = [list(truth.image_names).index(n) for n in cameras.image_names]
    scale, rotation, translation = umeyama(cameras.centres, truth.centres[order])
    error = np.linalg.norm(scale * cameras.centres @ rotation.T + translation - truth.centres[order], axis=1)
    assert error.max() < 0.01 * 1.6
    assert rotation_error_deg(truth.c2w[order], rotation, cameras.c2w).max() < 1.0
    assert sorted(p.name for p in undistorted.iterdir()) == sorted(cameras.image_names)
    assert {p.name for p in kept.iterdir()} == {"database.db", "sparse", "points.ply"}
    differences = []
    for name, K_new in zip(cameras.image_names, cameras.K):
        image = cv2.imread(str(undistorted / name)).astype(np.float64)
        assert image.shape[:2] == (cameras.height, cameras.width)
        index = list(truth.image_names).index(name)
        pinhole = cv2.imread(str(folder / name))
        expected = resample(pinhole, truth.K[index], K_new, cameras.width, cameras.height).astype(np.float64)
        differences.append(np.abs(image - expected)[8:-8, 8:-8].mean())
        # the same images left distorted would be far off
        wrong = cv2.resize(cv2.imread(str(distorted / name)), (cameras.width, cameras.height)).astype(
            np.float64
        )
        assert np.abs(wrong - expected)[8:-8, 8:-8].mean() > 2 * differences[-1]
    assert np.mean(differences) < 4.0  # of 255 (measured 1.6): interpolated twice, no geometric error


def test_a_distorted_model_needs_a_folder_for_the_undistorted_images(eight_views):
    with pytest.raises(ValueError, match="undistorted images"):
        sfm.run_sfm(eight_views[0], settings=sfm.SfmSettings(camera_model="OPENCV"))
