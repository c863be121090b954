"""Ray bending on a hand-built field: a red box above a green floor, seen from above."""

import numpy as np
import pytest
import torch

from fignetctl.core import rerender
from fignetctl.core.nerf import NerfConfig, NerfModel
from fignetctl.core.pinhole import Camera, look_at
from fignetctl.core.pinhole import pixel_of as pixel_of_point
from fignetctl.core.transforms import quat_from_axis_angle
from fignetctl.core.volume import Volume
from fignetctl.core.volume import write_volume as write_volume_file
from fignetctl.errors import FignetError

BOX_LOWER, BOX_UPPER = np.array([-0.3, -0.15, -0.6]), np.array([0.3, 0.15, -0.2])  # long along x
FLOOR_TOP = -0.8
CAMERA_HEIGHT = 3.0


def solid_field(resolution=41):
    """NerfModel on [-1, 1]³: an opaque red box (BOX_LOWER..BOX_UPPER) and a green floor slab
    below z = FLOOR_TOP, empty elsewhere, black background, occupancy refreshed."""
    config = NerfConfig(
        grid_resolution_initial=resolution,
        grid_resolution=resolution,
        feature_resolution=resolution,
        feature_channels=4,
        mlp_width=8,
        background="black",
    )
    torch.manual_seed(0)
    model = NerfModel(config, [[-1, -1, -1], [1, 1, 1]])
    axis = torch.linspace(-1, 1, resolution)
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")
    points, eps = torch.stack([x, y, z], dim=-1), 1e-4  # box faces on grid vertices, kept despite rounding
    in_box = ((points >= torch.tensor(BOX_LOWER - eps)) & (points <= torch.tensor(BOX_UPPER + eps))).all(-1)
    in_floor = z <= FLOOR_TOP + eps
    with torch.no_grad():
        model.field.density_grid.fill_(-30.0)
        model.field.density_grid[0, 0][in_box | in_floor] = 40.0
        features = torch.full((4, resolution, resolution, resolution), -6.0)
        features[0][in_box] = 6.0  # red
        features[1][in_floor] = 6.0  # green
        model.field.feature_grid.copy_(features[None])
    model.refresh_occupancy()
    return model.eval()


def top_camera(size=48, focal=60.0):
    """(K, c2w, width, height) above the scene looking straight down (image x = world x, image v = -y)."""
    K = np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1.0]])
    return Camera(K, look_at([0, 0, CAMERA_HEIGHT], [0, 0, 0]), size, size)


def motion_of(positions, quaternions=None, origin=None):
    """ObjectMotion of the box, rest origin at its centre."""
    origin = 0.5 * (BOX_LOWER + BOX_UPPER) if origin is None else origin
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    quaternions = (
        np.tile([1.0, 0, 0, 0], (len(positions), 1)) if quaternions is None else np.asarray(quaternions)
    )
    from fignetctl.core.transforms import quat_to_matrix

    return rerender.ObjectMotion(quat_to_matrix(quaternions), positions, origin, "box", 0.1)


def make_volume(lower, upper, origin):
    """A volume.npz's contents: V_o, its origin, and an environment box below it."""
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    return Volume(lower, upper, np.asarray(origin, np.float64), lower - [0, 0, 0.3], upper)


VOLUME = make_volume(BOX_LOWER - 0.05, BOX_UPPER + 0.05, 0.5 * (BOX_LOWER + BOX_UPPER))
REST = 0.5 * (BOX_LOWER + BOX_UPPER)


def pixel_of(camera, point):
    pixels, _ = camera.project(np.asarray(point, np.float64)[None])
    u, v = pixel_of_point(pixels)[0]
    return v, u


@pytest.fixture(scope="module")
def field():
    return solid_field()


def test_background_is_the_models_own_render(field):
    camera = top_camera()
    background = rerender.Rerenderer(field, VOLUME, motion_of([REST])).background(camera)
    reference = field.render(camera)
    np.testing.assert_allclose(background["rgb"].reshape(reference.rgb.shape), reference.rgb, atol=1e-5)
    np.testing.assert_allclose(background["depth"].reshape(reference.depth.shape), reference.depth, atol=1e-5)
    v, u = pixel_of(camera, REST)
    assert reference.rgb[v, u, 0] > 0.9 and reference.depth[v, u] == pytest.approx(
        CAMERA_HEIGHT + 0.2, abs=0.04
    )


@pytest.mark.parametrize("mode", rerender.MODES)
def test_identity_bending_equals_the_unedited_render(field, mode):
    camera = top_camera()
    renderer = rerender.Rerenderer(field, VOLUME, motion_of([REST]), mode)
    frame = renderer.render(camera, 0)
    unedited = field.render(camera)
    assert frame.bent.any()
    np.testing.assert_allclose(frame.rgb, unedited.rgb, atol=1e-5)
    np.testing.assert_allclose(frame.depth, unedited.depth, atol=1e-4)
    np.testing.assert_allclose(frame.opacity, unedited.opacity, atol=1e-5)


def test_move_shows_the_box_at_its_new_place_and_the_floor_at_the_old(field):
    camera, shift = top_camera(), np.array([0.55, 0.3, 0.1])
    frame = rerender.Rerenderer(field, VOLUME, motion_of([REST + shift]), "move").render(camera, 0)
    new_v, new_u = pixel_of(camera, REST + shift)
    old_v, old_u = pixel_of(camera, REST)
    assert frame.rgb[new_v, new_u, 0] > 0.9 and frame.opacity[new_v, new_u] > 0.99
    assert frame.depth[new_v, new_u] == pytest.approx(CAMERA_HEIGHT + 0.2 - 0.1, abs=0.04)
    assert frame.rgb[old_v, old_u, 1] > 0.5 and frame.rgb[old_v, old_u, 0] < 0.1  # the floor behind
    assert frame.depth[old_v, old_u] == pytest.approx(CAMERA_HEIGHT - FLOOR_TOP, abs=0.04)


def test_move_by_less_than_the_box_leaves_no_ghost_at_the_old_place(field):
    camera, shift = top_camera(), np.array([0.25, 0.0, 0.0])  # the boxes overlap
    frame = rerender.Rerenderer(field, VOLUME, motion_of([REST + shift]), "move").render(camera, 0)
    v, u = pixel_of(camera, REST + [-0.27, 0, 0])  # the old box's end, which R_t·x reads from inside V_o
    assert frame.rgb[v, u, 1] > 0.5 and frame.rgb[v, u, 0] < 0.1  # floor, not a ghost of the box
    v, u = pixel_of(camera, REST + shift + [0.15, 0, 0])
    assert frame.rgb[v, u, 0] > 0.5 and frame.rgb[v, u, 1] < 0.1 and frame.opacity[v, u] > 0.99


def test_duplicate_shows_both(field):
    camera, shift = top_camera(), np.array([-0.55, -0.3, 0.0])
    frame = rerender.Rerenderer(field, VOLUME, motion_of([REST + shift]), "duplicate").render(camera, 0)
    for point in (REST, REST + shift):
        v, u = pixel_of(camera, point)
        assert frame.rgb[v, u, 0] > 0.9 and frame.depth[v, u] == pytest.approx(CAMERA_HEIGHT + 0.2, abs=0.04)


def test_rays_missing_both_boxes_are_bit_identical_to_the_background(field):
    camera = top_camera()
    renderer = rerender.Rerenderer(field, VOLUME, motion_of([REST + [0.5, 0.4, 0.0]]), "move")
    frame = renderer.render(camera, 0)
    background = renderer.background(camera)
    untouched = ~frame.bent.reshape(-1)
    assert 0.5 < untouched.mean() < 0.98
    assert np.array_equal(frame.rgb.reshape(-1, 3)[untouched], background["rgb"][untouched])
    assert np.array_equal(frame.depth.reshape(-1)[untouched], background["depth"][untouched])


def test_bent_pixels_are_exactly_those_whose_rays_meet_a_box(field):
    camera = top_camera()
    motion = motion_of([REST + [0.5, 0.4, 0.0]])
    frame = rerender.Rerenderer(field, VOLUME, motion, "move").render(camera, 0)
    # Independent reference: dense points along every ray, inside either box.
    origins, directions = camera.rays()
    t = np.linspace(2.0, 4.5, 1001)
    points = origins[:, None] + t[None, :, None] * directions[:, None]
    in_box = lambda p: ((p >= VOLUME.lower) & (p <= VOLUME.upper)).all(-1)
    rest = motion.inverse(0, points.reshape(-1, 3)).reshape(points.shape)
    expected = (in_box(points) | in_box(rest)).any(-1)
    disagree = frame.bent.reshape(-1) != expected
    assert disagree.sum() <= 2  # grazing rays between the dense samples


def test_rotation_turns_the_box_and_its_sample_directions(field):
    camera = top_camera()
    quarter = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi / 2)
    frame = rerender.Rerenderer(field, VOLUME, motion_of([REST], [quarter]), "move").render(camera, 0)
    along_y = pixel_of(camera, REST + [0, 0.2, 0.0])  # the long side now runs along y
    along_x = pixel_of(camera, REST + [0.25, 0, 0.0])
    assert frame.opacity[along_y] > 0.99 and frame.rgb[along_y][0] > 0.9
    assert frame.rgb[along_x][1] > 0.5 and frame.rgb[along_x][0] < 0.1  # floor where the box was long before


def test_object_moved_out_of_the_scene_box_stays_whole(field):
    camera = top_camera()
    frame = rerender.Rerenderer(field, VOLUME, motion_of([REST + [0, 0, 1.4]]), "move").render(camera, 0)
    v, u = pixel_of(camera, REST + [0, 0, 1.4])
    assert frame.rgb[v, u, 0] > 0.9
    assert frame.depth[v, u] == pytest.approx(
        CAMERA_HEIGHT - (BOX_UPPER[2] + 1.4), abs=0.04
    )  # top above the scene box


def test_warp_maps_points_as_written(field):
    motion = motion_of([REST + [0.5, 0, 0]])
    warp = rerender.make_warp(motion, 0, VOLUME, "move")
    points = torch.tensor(np.array([REST + [0.5, 0, 0], REST, [0.9, 0.9, 0.9]]), dtype=torch.float32)
    bent, _ = warp(points, torch.ones_like(points))
    np.testing.assert_allclose(bent.numpy(), [REST, REST + [0.5, 0, 0], [0.9, 0.9, 0.9]], atol=1e-6)
    end = torch.tensor(np.array([REST + [-0.3, 0, 0]]), dtype=torch.float32)
    bent, _ = rerender.make_warp(motion_of([REST + [0.1, 0, 0]]), 0, VOLUME, "move")(end, end)
    assert (bent > 1e5).all()  # R_t·x lands in V_o again: empty, not the object twice
    bent, _ = rerender.make_warp(motion, 0, VOLUME, "duplicate")(points, torch.ones_like(points))
    np.testing.assert_allclose(bent.numpy()[1], REST, atol=1e-6)


def test_trace_is_drawn():
    image = np.zeros((48, 48, 3), np.uint8)
    rerender.draw_trace(image, top_camera(), np.array([[-0.5, 0, 0], [0, 0, 0], [0.5, 0.2, 0]]))
    assert (image[..., 0] > 200).sum() > 20


# ----------------------------------------------------------------------------- inputs


def write_volume(path, lower=VOLUME.lower, upper=VOLUME.upper, origin=VOLUME.origin):
    return write_volume_file(path, make_volume(lower, upper, origin))


def test_object_mismatch_is_refused():
    half = 0.5 * (BOX_UPPER - BOX_LOWER)
    corners = rerender.box_corners(-half, half)
    rerender.check_object_fits_volume(corners, "box", VOLUME)
    with pytest.raises(FignetError, match="does not fit"):
        rerender.check_object_fits_volume(corners * 2.0, "box", VOLUME)
    with pytest.raises(FignetError, match="does not fit"):  # the right mesh about another origin
        rerender.check_object_fits_volume(corners + [0.3, 0, 0], "box", VOLUME)
