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
    normal, _centroid, mask = wa.fit_plane_ransac(scene.points, threshold=0.005, seed=0)
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


def room_scene(seed=0, walls=True, floor=True, ring_height=None) -> Cameras:
    """Cameras 0.5 m above a 1 × 0.7 m table top at z = 0 (2 mm noise), looking at objects on it;
    optionally a 6 × 6 m floor 0.75 m below (hidden under the table), the room's walls (0.75 m
    below to 1.85 m above the table: at the table's height they hold more points than the
    table), and a ring of points round a 3 × 3 m square at `ring_height` (a rim, a backdrop)."""
    rng = np.random.default_rng(seed)
    c2w = ring_cameras(16, radius=0.9, height=0.5)
    parts = [
        np.column_stack([rng.uniform([-0.5, -0.35], [0.5, 0.35], (600, 2)), rng.normal(0, 0.002, 600)]),
        rng.uniform([-0.2, -0.2, 0.01], [0.2, 0.2, 0.2], (100, 3)),  # objects on the table
    ]
    if floor:
        ground = np.column_stack([rng.uniform(-3, 3, (1500, 2)), rng.normal(-0.75, 0.003, 1500)])
        parts.append(ground[(np.abs(ground[:, 0]) > 0.5) | (np.abs(ground[:, 1]) > 0.35)])
    if walls:
        along, side = rng.uniform(-3, 3, 2400), rng.integers(0, 4, 2400)
        wall = np.column_stack([along, np.full(2400, 3.0), rng.uniform(-0.75, 1.85, 2400)])
        parts.append(np.array([_turn(p, s) for p, s in zip(wall, side)]))
    if ring_height is not None:
        along, side = rng.uniform(-1.5, 1.5, 500), rng.integers(0, 4, 500)
        ring = np.column_stack([along, np.full(500, 1.5), np.full(500, ring_height)])
        parts.append(np.array([_turn(p, s) for p, s in zip(ring, side)]))
    points = np.concatenate(parts)
    K = np.tile(np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]]), (len(c2w), 1, 1))
    names = np.array([f"view_{i:03d}.png" for i in range(len(c2w))])
    return Cameras(names, K, c2w, 320, 240, points, np.zeros((len(points), 3), np.uint8))


def _turn(point, quarter_turns):
    """`point` turned by quarter_turns × 90° about z."""
    x, y, z = point
    for _ in range(quarter_turns):
        x, y = -y, x
    return np.array([x, y, z])


def level_tilt_deg(aligned: Cameras, truth: Cameras) -> float:
    """Angle between the aligned frame's z and the true z (through the similarity of the centres)."""
    _, rotation, _ = wa.umeyama(aligned.centres, truth.centres)
    return float(np.degrees(np.arccos(np.clip((rotation @ [0, 0, 1.0])[2], -1, 1))))


def test_a_table_in_a_room_is_found_without_its_walls_and_levelled_on():
    """The table's height band also holds the walls' points at that height (more of them than the
    table's): only the table's connected patch is the plane, so both planes are listed with the
    right heights and extents, and by default (the cameras look at the objects on the table)
    the table is z = 0 and --camera-height from it gives the scale."""
    rng = np.random.default_rng(7)
    truth = room_scene()
    sfm_frame = moved(truth, 0.37, random_rotation(rng), np.array([1.0, 2.0, -0.5]))
    for choice in ("auto", "highest"):
        aligned, alignment = wa.align(
            sfm_frame, wa.AlignmentSettings(support_plane=choice, camera_height=0.5)
        )
        table, floor = alignment.planes
        assert (table["chosen"], floor["chosen"]) == (True, False), choice
        assert table["height"] == 0.0 and floor["height"] == pytest.approx(-0.75, abs=0.005)
        assert table["extent"] == pytest.approx([0.9, 0.63], rel=0.05)  # 5–95 %, longest first
        assert floor["extent"] == pytest.approx([5.4, 5.4], rel=0.08)
        assert alignment.scale * 0.37 == pytest.approx(1.0, rel=0.002)
        assert level_tilt_deg(aligned, truth) < 0.1
        table_points = aligned.points[:600]
        assert abs(np.median(table_points[:, 2])) < 0.002  # z = 0 is the table top, to 2 mm
    _, lowest = wa.align(sfm_frame, wa.AlignmentSettings(support_plane="lowest", camera_height=1.25))
    assert [p["chosen"] for p in lowest.planes] == [False, True]
    assert lowest.scale * 0.37 == pytest.approx(1.0, rel=0.005)
    assert [round(p["height"], 2) for p in lowest.planes] == [0.75, 0.0]


def test_a_lone_table_top_is_the_one_plane():
    rng = np.random.default_rng(8)
    truth = room_scene(walls=False, floor=False)
    aligned, alignment = wa.align(
        moved(truth, 2.0, random_rotation(rng), np.zeros(3)), wa.AlignmentSettings(camera_height=0.5)
    )
    assert len(alignment.planes) == 1 and alignment.planes[0]["chosen"]
    assert alignment.planes[0]["extent"] == pytest.approx([0.9, 0.63], rel=0.05)
    assert level_tilt_deg(aligned, truth) < 0.1
    assert abs(np.median(aligned.points[:600, 2])) < 0.002
    np.testing.assert_allclose(aligned.centres[:, 2], 0.5, atol=0.002)


def test_a_ring_of_points_at_one_height_is_not_a_plane():
    """Points round a 3 × 3 m square at one height (walls' bottoms, a backdrop, a rim), even when
    they outnumber the table's: not listed, not chosen with any --support-plane."""
    truth = room_scene(walls=False, floor=False, ring_height=-0.3)
    ring = truth.points[-500:]
    assert wa._compact_plane(truth, ring, np.array([0, 0, 1.0]), ring[0], wa.AlignmentSettings()) is None
    for choice in wa.SUPPORT_CHOICES:
        aligned, alignment = wa.align(truth, wa.AlignmentSettings(support_plane=choice, camera_height=0.5))
        assert len(alignment.planes) == 1, (choice, alignment.planes)
        assert abs(np.median(aligned.points[:600, 2])) < 0.002, choice


def test_largest_cluster_keeps_one_patch():
    rng = np.random.default_rng(9)
    patch = rng.uniform(0, 1, (400, 2))
    far = rng.uniform(5, 5.3, (150, 2))  # denser, but fewer
    mask = wa._largest_cluster(np.concatenate([patch, far]))
    assert mask[:400].all() and not mask[400:].any()
