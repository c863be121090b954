"""Gravity and scale alignment against exact answers."""

import dataclasses

import numpy as np
import pytest

from fignetctl.core import world_alignment as wa
from fignetctl.core.cameras import Cameras
from fignetctl.core.transforms import quat_to_matrix
from fignetctl.errors import FignetError
from tests.core.synthetic_views import ring_cameras


def random_rotation(rng):
    q = rng.normal(size=4)
    return quat_to_matrix(q / np.linalg.norm(q))


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def table_scene(count=10, height=0.5, points=400, clutter=100, seed=0) -> Cameras:
    """Exact cameras on a ring above a z = 0 table with points on it and some clutter above."""
    rng = np.random.default_rng(seed)
    c2w = ring_cameras(count, radius=0.8, height=height)
    table = np.column_stack([rng.uniform(-0.5, 0.5, (points, 2)), np.zeros(points)])
    boxes = rng.uniform([-0.2, -0.2, 0.02], [0.2, 0.2, 0.25], (clutter, 3))
    K = np.tile(np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]]), (count, 1, 1))
    names = np.array([f"view_{i:03d}.png" for i in range(count)])
    all_points = np.concatenate([table, boxes])
    return Cameras(names, K, c2w, 320, 240, all_points, np.zeros((len(all_points), 3), np.uint8))


def moved(cameras: Cameras, scale, rotation, translation) -> Cameras:
    return wa.apply_similarity(cameras, scale, rotation, translation)


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(1)
    source = rng.normal(size=(20, 3))
    rotation, scale, translation = random_rotation(rng), 2.7, np.array([1.0, -3.0, 0.5])
    target = scale * source @ rotation.T + translation
    s, R, t = wa.umeyama(source, target)
    assert s == pytest.approx(scale, rel=1e-12)
    np.testing.assert_allclose(R, rotation, atol=1e-12)
    np.testing.assert_allclose(t, translation, atol=1e-12)


def test_rotation_between_takes_a_to_b_including_opposite():
    rng = np.random.default_rng(2)
    for a in [rng.normal(size=3), np.array([0, 0, -1.0]), np.array([0, 0, 1.0])]:
        R = wa.rotation_between(a, [0, 0, 1])
        np.testing.assert_allclose(R @ (a / np.linalg.norm(a)), [0, 0, 1], atol=1e-12)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)


def test_ransac_plane_ignores_clutter():
    scene = table_scene()
    normal, centroid, mask = wa.fit_plane_ransac(scene.points, threshold=0.005, seed=0)
    assert angle_deg(np.abs(normal), np.array([0, 0, 1.0])) < 1e-6
    assert mask[:400].all() and mask[400:].sum() < 5


def test_tilted_scene_is_levelled_and_scaled_exactly():
    """A similarity of an exact table scene is undone: plane level within 0.1°, z = 0, metres."""
    rng = np.random.default_rng(3)
    truth = table_scene(height=0.5)
    rotation, scale, translation = random_rotation(rng), 3.1, rng.normal(size=3)
    reconstructed = moved(truth, scale, rotation, translation)
    aligned, alignment = wa.align(reconstructed, wa.AlignmentSettings(camera_height=0.5))
    assert alignment.gravity_source == "plane"
    table = aligned.points[:400]
    assert np.abs(table[:, 2]).max() < 1e-9
    normal, _ = wa.fit_plane_least_squares(table)
    assert angle_deg(np.abs(normal), np.array([0, 0, 1.0])) < 0.1
    assert aligned.centres[:, 2].mean() == pytest.approx(0.5, rel=1e-9)
    # The same as the truth up to a rotation about z and a horizontal shift.
    s, R, t = wa.umeyama(aligned.centres, truth.centres)
    assert s == pytest.approx(1.0, rel=1e-9)
    assert angle_deg(R @ [0, 0, 1.0], np.array([0, 0, 1.0])) < 1e-6
    assert abs(t[2]) < 1e-9


def test_noisy_tilted_plane_within_a_tenth_of_a_degree():
    rng = np.random.default_rng(4)
    truth = table_scene(points=2000, clutter=300)
    noisy = dataclasses.replace(truth, points=truth.points + rng.normal(0, 0.002, truth.points.shape))
    tilted = moved(noisy, 1.0, wa.rotation_between([0, 0, 1.0], [0.3, 0.1, 1.0]), np.zeros(3))
    aligned, _ = wa.align(tilted, wa.AlignmentSettings(camera_height=0.5))
    normal, _ = wa.fit_plane_least_squares(aligned.points[:2000])
    assert angle_deg(np.abs(normal), np.array([0, 0, 1.0])) < 0.1


def test_baseline_scale():
    truth = table_scene()
    reconstructed = moved(truth, 0.2, np.eye(3), np.zeros(3))
    distance = np.linalg.norm(truth.centres[0] - truth.centres[3])
    settings = wa.AlignmentSettings(baseline=("view_000.png", "view_003.png", distance))
    aligned, alignment = wa.align(reconstructed, settings)
    assert alignment.scale == pytest.approx(5.0, rel=1e-9)
    assert np.linalg.norm(aligned.centres[0] - aligned.centres[3]) == pytest.approx(distance)


def test_camera_up_fallback_without_points():
    truth = dataclasses.replace(
        table_scene(), points=np.zeros((0, 3)), point_colors=np.zeros((0, 3), np.uint8)
    )
    rotation = random_rotation(np.random.default_rng(5))
    aligned, alignment = wa.align(
        moved(truth, 2.0, rotation, np.ones(3)), wa.AlignmentSettings(camera_height=0.5)
    )
    assert alignment.gravity_source == "cameras"
    # The ring cameras look down 32°, so their mean up is tilted; it is only a fallback.
    # The mean up of cameras on a full ring, each tilted towards the centre, is vertical.
    assert angle_deg(aligned.c2w[:, :3, 1].mean(axis=0) * -1, np.array([0, 0, 1.0])) < 1e-6
    with pytest.raises(FignetError, match="no support plane"):
        wa.align(truth, wa.AlignmentSettings(gravity="plane"))


def test_plane_normal_points_toward_the_cameras():
    truth = table_scene()
    flipped = moved(truth, 1.0, wa.rotation_between([0, 0, 1.0], [0, 0, -1.0]), np.zeros(3))
    aligned, _ = wa.align(flipped, wa.AlignmentSettings(gravity="plane", camera_height=0.5))
    assert (aligned.centres[:, 2] > 0).all()


def test_gravity_none_keeps_the_frame():
    truth = table_scene()
    aligned, alignment = wa.align(truth, wa.AlignmentSettings(gravity="none"))
    np.testing.assert_array_equal(aligned.c2w, truth.c2w)
    assert alignment.scale == 1.0


def table_on_floor(seed=0) -> Cameras:
    """Cameras 0.5 m above a 1 × 1 m table top at z = 0.75 on a 3 × 3 m floor at z = 0 (the floor
    holding more points), with clutter on the table."""
    rng = np.random.default_rng(seed)
    c2w = ring_cameras(12, radius=0.9, height=1.25)
    floor = np.column_stack([rng.uniform(-1.5, 1.5, (700, 2)), np.zeros(700)])
    floor = floor[np.abs(floor[:, :2]).max(axis=1) > 0.5]  # under the table it is hidden
    table = np.column_stack([rng.uniform(-0.5, 0.5, (400, 2)), np.full(400, 0.75)])
    clutter = rng.uniform([-0.2, -0.2, 0.77], [0.2, 0.2, 1.0], (80, 3))
    points = np.concatenate([floor, table, clutter])
    K = np.tile(np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]]), (12, 1, 1))
    names = np.array([f"view_{i:03d}.png" for i in range(12)])
    return Cameras(names, K, c2w, 320, 240, points, np.zeros((len(points), 3), np.uint8))


def test_a_table_on_a_floor_lists_both_planes_and_the_table_can_be_chosen():
    rng = np.random.default_rng(4)
    truth = table_on_floor()
    sfm_frame = moved(truth, 2.7, random_rotation(rng), np.array([0.3, -1.0, 2.0]))
    largest = wa.find_alignment(sfm_frame, wa.AlignmentSettings(camera_height=1.25))
    assert [round(p["height"], 2) for p in largest.planes] == [0.75, 0.0]  # highest first
    assert [p["chosen"] for p in largest.planes] == [False, True]  # the floor holds more points
    assert largest.scale * 2.7 == pytest.approx(1.0, rel=0.01)
    table, floor = largest.planes
    assert table["share"] == pytest.approx(400 / len(truth.points), abs=0.02)
    assert floor["extent"][0] == pytest.approx(2.7, rel=0.1) and table["extent"][0] == pytest.approx(
        0.9, rel=0.1
    )
    aligned, highest = wa.align(sfm_frame, wa.AlignmentSettings(support_plane="highest", camera_height=0.5))
    assert [p["chosen"] for p in highest.planes] == [True, False]
    assert [round(p["height"], 3) for p in highest.planes] == [0.0, -0.75]
    assert highest.scale * 2.7 == pytest.approx(1.0, rel=0.01)  # camera height from the table
    np.testing.assert_allclose(aligned.centres[:, 2], 0.5, atol=0.005)
    lowest = wa.find_alignment(sfm_frame, wa.AlignmentSettings(support_plane="lowest", camera_height=1.25))
    assert [p["chosen"] for p in lowest.planes] == [False, True]


def test_capture_poses_prints_the_planes_it_found(tmp_path):
    from click.testing import CliRunner

    from fignetctl.cli import cli
    from fignetctl.core.cameras import read_cameras, write_cameras

    rng = np.random.default_rng(5)
    write_cameras(tmp_path / "sfm.npz", moved(table_on_floor(), 0.4, random_rotation(rng), np.zeros(3)))
    args = ["capture-poses", "--import-cameras", str(tmp_path / "sfm.npz"), "--support-plane", "highest"]
    result = CliRunner().invoke(cli, [*args, "--camera-height", "0.5", "-o", str(tmp_path / "c.npz")])
    assert result.exit_code == 0, result.output
    assert "2 horizontal planes" in result.stderr and "-> z = +0.000 m" in result.stderr
    assert "z = -0.750 m" in result.stderr
    np.testing.assert_allclose(read_cameras(tmp_path / "c.npz").centres[:, 2], 0.5, atol=0.005)
