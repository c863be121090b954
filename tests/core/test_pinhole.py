"""The one pixel convention (pixel (u, v) is the image point (u + 0.5, v + 0.5)) against COLMAP,
both ways, and for every producer of cameras."""

import numpy as np
import pytest

from fignetctl.core import cameras, pinhole

RNG = np.random.default_rng(0)
WIDTH, HEIGHT = 64, 48


def random_camera(seed=0):
    rng = np.random.default_rng(seed)
    K = np.array(
        [
            [rng.uniform(40, 80), 0, rng.uniform(20, 44)],
            [0, rng.uniform(40, 80), rng.uniform(16, 32)],
            [0, 0, 1],
        ]
    )
    eye = rng.normal(size=3) * 2
    return pinhole.Camera(K, pinhole.look_at(eye, eye + rng.normal(size=3)), WIDTH, HEIGHT)


def test_a_pixels_ray_passes_through_the_point_that_projects_to_its_centre():
    camera = random_camera()
    origins, directions = pinhole.pixel_rays(camera.K, camera.c2w, WIDTH, HEIGHT)
    depth = RNG.uniform(0.5, 5.0, (HEIGHT, WIDTH))
    points = origins + depth[..., None] * directions
    image, z = camera.project(points.reshape(-1, 3))
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    centres = np.stack([u, v], -1).reshape(-1, 2) + 0.5
    np.testing.assert_allclose(image, centres, atol=1e-9)
    np.testing.assert_allclose(z, depth.reshape(-1), rtol=1e-12)  # ray parameters are z-depths
    np.testing.assert_array_equal(pinhole.pixel_of(image), np.stack([u, v], -1).reshape(-1, 2))
    back = pinhole.unproject(camera.K, camera.c2w, u.reshape(-1), v.reshape(-1), depth.reshape(-1))
    np.testing.assert_allclose(back, points.reshape(-1, 3), atol=1e-9)
    local = pinhole.camera_frame_points(depth, camera.K)
    np.testing.assert_allclose(local @ camera.c2w[:3, :3].T + camera.eye, points, atol=1e-9)


def test_projection_and_rays_match_colmap():
    pycolmap = pytest.importorskip("pycolmap")
    camera = random_camera(1)
    (fx, _, cx), (_, fy, cy) = camera.K[:2]
    colmap = pycolmap.Camera(model="PINHOLE", width=WIDTH, height=HEIGHT, params=[fx, fy, cx, cy])
    np.testing.assert_allclose(colmap.calibration_matrix(), camera.K)
    local = np.column_stack([RNG.uniform(-1, 1, (50, 2)), RNG.uniform(0.5, 3, 50)])
    world = local @ camera.c2w[:3, :3].T + camera.eye
    np.testing.assert_allclose(camera.project(world)[0], colmap.img_from_cam(local), atol=1e-9)
    u, v = RNG.integers(0, WIDTH, 20), RNG.integers(0, HEIGHT, 20)
    colmap_rays = colmap.cam_from_img(np.column_stack([u + 0.5, v + 0.5]))  # (x/z, y/z)
    np.testing.assert_allclose(pinhole.camera_directions(camera.K, u, v)[:, :2], colmap_rays, atol=1e-12)


def colmap_default_K():
    pycolmap = pytest.importorskip("pycolmap")
    colmap = pycolmap.Camera(model="SIMPLE_PINHOLE", width=WIDTH, height=HEIGHT, params=[55, 32, 24])
    return colmap.calibration_matrix()


@pytest.mark.parametrize(
    "make_K",
    [
        lambda: pinhole.intrinsics_from_fov(WIDTH, HEIGHT, 50.0),
        lambda: cameras._frame_K({"camera_angle_x": 0.9}, WIDTH, HEIGHT),
        colmap_default_K,
    ],
    ids=["fov (rerender, show)", "transforms.json", "COLMAP"],
)
def test_centred_cameras_have_mirror_symmetric_pixel_rays(make_K):
    """A camera centred in its image (each producer's default) sees pixel (u, v) and pixel
    (W − 1 − u, H − 1 − v) on rays mirrored about the optical axis."""
    K = np.asarray(make_K(), np.float64)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    rays = pinhole.camera_directions(K, u, v)
    mirrored = pinhole.camera_directions(K, WIDTH - 1 - u, HEIGHT - 1 - v)
    np.testing.assert_allclose(rays[..., :2], -mirrored[..., :2], atol=1e-12)


def test_resized_images_keep_every_point_at_the_same_fraction_of_the_image():
    camera = random_camera(2)
    points = camera.eye + camera.c2w[:3, 2] * 2.0 + RNG.normal(size=(30, 3)) * 0.3
    image, _ = camera.project(points)
    for sx, sy in ((0.5, 0.5), (0.3125, 0.25), (2.0, 3.0)):
        scaled = pinhole.scale_intrinsics(camera.K, sx, sy)
        resized, _ = pinhole.project(scaled, camera.c2w, points)
        np.testing.assert_allclose(resized, image * [sx, sy], atol=1e-9)


def test_look_at_and_orbit_look_at_the_target():
    centre = np.array([0.2, -0.1, 0.3])
    poses = pinhole.orbit(centre, 2.0, 30.0, 12, azimuth_deg=10.0)
    assert poses.shape == (12, 4, 4)
    for c2w in poses:
        np.testing.assert_allclose(np.linalg.norm(c2w[:3, 3] - centre), 2.0)
        np.testing.assert_allclose(c2w[:3, :3].T @ c2w[:3, :3], np.eye(3), atol=1e-12)
        assert np.linalg.det(c2w[:3, :3]) == pytest.approx(1.0)
        np.testing.assert_allclose(c2w[2, 3] - centre[2], 2.0 * np.sin(np.radians(30.0)))
        camera = pinhole.Camera(pinhole.intrinsics_from_fov(WIDTH, HEIGHT, 40.0), c2w, WIDTH, HEIGHT)
        image, _depth = camera.project(centre[None])
        np.testing.assert_allclose(image[0], [WIDTH / 2, HEIGHT / 2], atol=1e-9)  # in the middle
        assert camera.c2w[2, 1] < 0  # image y (down) points down in the world (z up)
    down = pinhole.look_at([0, 0, 3], [0, 0, 0])
    np.testing.assert_allclose(down[:3, 0], [1, 0, 0])
