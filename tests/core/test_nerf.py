"""The radiance field: exact rendering of known fields, density queries, warp, file round trip,
training that lowers the loss, and exact resume. Tiny scenes made here; seconds each."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from fignetctl.core.cameras import Cameras, write_cameras
from fignetctl.core.nerf.config import NerfConfig
from fignetctl.core.nerf.io import load_nerf, save_nerf
from fignetctl.core.nerf.model import NerfModel, Rendering
from fignetctl.core.nerf.rays import scene_bounds
from fignetctl.core.nerf.renderer import (
    distortion,
    median_depth,
    per_sample,
    render_samples,
    sample_along_rays,
)
from fignetctl.core.nerf.training import make_trainer
from fignetctl.core.pinhole import look_at, pixel_rays
from fignetctl.errors import FignetError, FormatError

TINY = NerfConfig(
    max_image_side=32,
    holdout_every=4,
    grid_resolution_initial=24,
    grid_resolution=24,
    upsample_steps=(),
    feature_resolution=12,
    feature_channels=6,
    mlp_width=16,
    rays_per_batch=256,
    steps=30,
    occupancy_warmup=10,
    occupancy_every=5,
    checkpoint_every=1000,
)
BOUNDS = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


class ConstantBox:
    """An analytic field: density `sigma` inside [-h, h]^3, colour `rgb` everywhere."""

    def __init__(self, sigma, half=0.5, rgb=(1.0, 0.0, 0.0)):
        self.sigma, self.half, self.rgb = sigma, half, torch.tensor(rgb)

    def density(self, points):
        inside = (points.abs() <= self.half).all(dim=-1)
        return torch.where(inside, torch.full_like(points[:, 0], self.sigma), torch.zeros_like(points[:, 0]))

    def colour(self, points, directions):
        return self.rgb.expand(len(points), 3)


def orbit(n=8, radius=3.0, width=32, height=24, focal=30.0):
    K = np.array([[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1.0]])
    c2w = [
        look_at((radius * math.cos(a), radius * math.sin(a), 1.2 + 0.4 * math.sin(3 * a)), (0.0, 0.0, 0.0))
        for a in np.linspace(0, 2 * math.pi, n, endpoint=False)
    ]
    return np.repeat(K[None], n, 0), np.array(c2w)


def solid_box_model(config=TINY, half=0.5, raw=14.0):
    """A NerfModel whose density grid is high inside [-half, half]^3 and whose colour varies."""
    with torch.random.fork_rng():
        torch.manual_seed(0)
        model = NerfModel(config, BOUNDS, density_resolution=config.grid_resolution)
    shape = model.field.density_grid.shape[2:]
    axes = [torch.linspace(-1, 1, s) for s in shape]
    x, y, z = torch.meshgrid(*axes, indexing="ij")
    inside = (x.abs() <= half + 1e-6) & (y.abs() <= half + 1e-6) & (z.abs() <= half + 1e-6)
    with torch.no_grad():
        model.field.density_grid[0, 0] = torch.where(inside, torch.tensor(raw), torch.tensor(-20.0))
        fx, fy, fz = (torch.linspace(-1, 1, s) for s in model.field.feature_grid.shape[2:])
        gx, gy, gz = torch.meshgrid(fx, fy, fz, indexing="ij")
        model.field.feature_grid[0, 0], model.field.feature_grid[0, 1], model.field.feature_grid[0, 2] = (
            3 * gx,
            3 * gy,
            3 * gz,
        )
    model.refresh_occupancy()
    return model.eval()


def write_synthetic_scene(folder, n=8, width=32, height=24):
    """Images of a coloured box rendered by a known field, with cameras.npz; returns paths."""
    import cv2

    model = solid_box_model(dataclasses.replace(TINY, background="black"))
    K, c2w = orbit(n, width=width, height=height)
    images = folder / "images"
    images.mkdir(parents=True, exist_ok=True)
    names = []
    for i in range(n):
        rgb = model.render((K[i], c2w[i], width, height)).rgb
        names.append(f"view_{i:03d}.png")
        cv2.imwrite(str(images / names[-1]), (rgb[..., ::-1] * 255 + 0.5).astype(np.uint8))
    corners = np.array(np.meshgrid(*[[-0.5, 0.5]] * 3)).reshape(3, -1).T
    points = np.concatenate([corners, np.random.default_rng(0).uniform(-0.5, 0.5, (40, 3))])
    cameras = Cameras(np.array(names), K, c2w, width, height, points, np.zeros((len(points), 3), np.uint8))
    write_cameras(folder / "cameras.npz", cameras)
    return images, folder / "cameras.npz", cameras


# -- rendering against exact answers ---------------------------------------------------------


def test_constant_density_gives_beer_lambert_opacity_and_expected_depth():
    sigma, step = 1.5, 1e-3
    origins = torch.tensor([[0.0, 0.0, -3.0], [0.2, -0.1, -3.0]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])  # the second has |d| = 2
    low, high = torch.tensor([-1.0] * 3), torch.tensor([1.0] * 3)
    samples = sample_along_rays(origins, directions, low, high, step)
    rgb, depth, opacity, _ = render_samples(ConstantBox(sigma), None, samples, directions, torch.zeros(3))
    exact_opacity = 1 - math.exp(-sigma * 1.0)  # a chord of length 1 through the box
    # E[distance] inside the slab [2.5, 3.5]: a + 1/σ − L e^{−σL} / (1 − e^{−σL})
    exact_distance = 2.5 + 1 / sigma - 1.0 * math.exp(-sigma) / (1 - math.exp(-sigma))
    assert opacity.numpy() == pytest.approx([exact_opacity] * 2, abs=1e-3)
    assert depth[0].item() == pytest.approx(exact_distance, abs=2e-3)
    assert depth[1].item() == pytest.approx(exact_distance / 2, abs=2e-3)  # ray parameter, not distance
    assert rgb[:, 0].numpy() == pytest.approx([exact_opacity] * 2, abs=1e-3)


def test_median_depth_is_where_half_the_light_is_lost_and_haze_does_not_move_it():
    """In the constant-density slab of the test above, half the light is lost at
    a + ln(2 / (1 + e^{−σL})) / σ (a coarse step interpolates to it); a faint haze in front of
    an opaque face pulls Σ w t / Σ w towards the camera but leaves the median on the face."""
    sigma = 1.5
    origins = torch.tensor([[0.0, 0.0, -3.0], [0.2, -0.1, -3.0]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    low, high = torch.tensor([-1.0] * 3), torch.tensor([1.0] * 3)
    exact = 2.5 + math.log(2 / (1 + math.exp(-sigma))) / sigma
    for step in (1e-3, 0.05):
        samples = sample_along_rays(origins, directions, low, high, step)
        _, _, opacity, weights = render_samples(ConstantBox(sigma), None, samples, directions, torch.zeros(3))
        lengths = per_sample(samples.step) / directions.norm(dim=-1)[:, None]
        median = median_depth(weights, samples.t, lengths, opacity)
        assert median[0].item() == pytest.approx(exact, abs=0.1 * step + 1e-3)
        assert median[1].item() == pytest.approx(exact / 2, abs=0.1 * step + 1e-3)

    class HazeBeforeFace(ConstantBox):
        def density(self, points):  # 0.3 per unit over z in [-0.5, 0), opaque from z = 0
            z = points[..., 2]
            return torch.where(z >= 0, torch.full_like(z, 1e4), torch.where(z >= -0.5, 0.3, 0.0))

    samples = sample_along_rays(origins[:1], directions[:1], low, high, 1e-3)
    _, depth, opacity, weights = render_samples(
        HazeBeforeFace(0.0), None, samples, directions[:1], torch.zeros(3)
    )
    median = median_depth(weights, samples.t, per_sample(samples.step), opacity)
    # Σ w t / Σ w: the haze (λ = 0.3 over L = 0.5 from a = 2.5) and the face at 3 behind it
    haze = 2.5 * (1 - math.exp(-0.15)) + (1 - math.exp(-0.15) * 1.15) / 0.3
    assert depth.item() == pytest.approx(haze + 3.0 * math.exp(-0.15), abs=2e-3)
    assert depth.item() < 2.97
    assert median.item() == pytest.approx(3.0, abs=2e-3)
    nothing = median_depth(torch.zeros(1, 4), torch.arange(4.0)[None], torch.ones(1, 1), torch.zeros(1))
    assert nothing.item() == 0.0


def test_rendering_some_pixels_gives_those_of_the_whole_image():
    model = solid_box_model()
    K = np.array([[20.0, 0, 8.0], [0, 20.0, 6.0], [0, 0, 1]])
    camera = (K, look_at((0.3, -2.5, 1.5), (0.0, 0.0, 0.0)), 16, 12)
    whole = model.render(camera)
    pixels = np.zeros((12, 16), bool)
    pixels[3:9, 5:12] = True
    pixels[0, 0] = True
    part = model.render(camera, pixels=pixels)
    for name in Rendering._fields:
        np.testing.assert_allclose(getattr(part, name)[pixels], getattr(whole, name)[pixels], atol=1e-5)
        assert not getattr(part, name)[~pixels].any()
    assert (whole.median_depth[whole.opacity > 0.99] > 0).all()


def test_opaque_box_depth_is_its_face_and_misses_are_background():
    origins = torch.tensor([[0.0, 0.0, -3.0], [0.9, 0.9, -3.0]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    samples = sample_along_rays(origins, directions, torch.tensor([-1.0] * 3), torch.tensor([1.0] * 3), 1e-3)
    background = torch.tensor([0.0, 0.0, 1.0])
    rgb, depth, opacity, _ = render_samples(ConstantBox(1e5), None, samples, directions, background)
    assert depth[0].item() == pytest.approx(2.5, abs=2e-3) and opacity[0].item() == pytest.approx(1.0)
    assert opacity[1].item() == 0.0 and depth[1].item() == 0.0
    assert rgb.numpy() == pytest.approx(np.array([[1, 0, 0], [0, 0, 1.0]]), abs=1e-4)


def test_grid_box_renders_z_depth_of_its_face_for_a_camera():
    model = solid_box_model()
    width, height = 33, 25
    K = np.array([[20.0, 0, 16.5], [0, 20.0, 12.5], [0, 0, 1]])  # pixel (16, 12) on the optical axis
    c2w = look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0))
    rendering = model.render((K, c2w, width, height))
    voxel = 2.0 / 23
    # Centre pixel: the face y = -0.5 is at z-depth 2.5; off-centre pixels see the same plane.
    assert rendering.depth[12, 16] == pytest.approx(2.5, abs=voxel)
    assert rendering.depth[12, 19] == pytest.approx(2.5, abs=voxel)
    assert rendering.opacity[12, 16] > 0.99 and rendering.opacity[0, 0] < 1e-3 and rendering.depth[0, 0] == 0
    assert rendering.rgb.shape == (height, width, 3) and rendering.depth.shape == (height, width)


def test_density_inside_outside_and_numpy_in_numpy_out():
    model = solid_box_model()
    points = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [0.85, 0.0, 0.0], [5.0, 0.0, 0.0]])
    sigma = model.density(points)
    assert isinstance(sigma, np.ndarray) and sigma.shape == (4,)
    assert sigma[0] > 50 and sigma[1] > 50 and sigma[2] < 1e-3 and sigma[3] == 0.0
    assert torch.is_tensor(model.density(torch.zeros(2, 3)))


def test_identity_warp_equals_no_warp_and_a_shift_moves_the_box():
    model = solid_box_model()
    K, c2w = orbit(1)
    origins, directions = (
        torch.as_tensor(a.reshape(-1, 3), dtype=torch.float32) for a in pixel_rays(K[0], c2w[0], 32, 24)
    )
    with torch.no_grad():
        plain = model.render_rays(origins, directions)
        warped = model.render_rays(origins, directions, warp=lambda x: x.clone())
        shifted = model.render_rays(origins, directions, warp=lambda x: x - torch.tensor([0.0, 0.0, 0.3]))
    for key in plain:
        assert torch.allclose(plain[key], warped[key])
    assert not torch.allclose(plain["opacity"], shifted["opacity"])


def test_scene_bounds_cover_points_and_stop_at_surrounding_cameras():
    points = np.random.default_rng(0).uniform(
        [-50, -50, 0], [50, 50, 0.5], (500, 3)
    )  # a floor to the horizon
    _, c2w = orbit(8, radius=2.0)
    low, high = scene_bounds(points, c2w, margin=0.1)
    assert high[0] - low[0] < 15.0  # limited to the camera ring (+ its look-at distance) along x, y
    assert low[2] < 0.0 and high[2] > 0.5


# -- files ------------------------------------------------------------------------------------


def test_save_load_round_trip_renders_the_same(tmp_path):
    model = solid_box_model()
    save_nerf(tmp_path / "nerf.pt", model, metrics={"held_out_psnr": 30.0})
    loaded = load_nerf(tmp_path / "nerf.pt")
    camera = (*orbit(1), 32, 24)
    camera = (camera[0][0], camera[1][0], 32, 24)
    assert np.allclose(loaded.render(camera).rgb, model.render(camera).rgb)
    assert loaded.metrics["held_out_psnr"] == 30.0 and np.allclose(loaded.bounds, BOUNDS)


@pytest.mark.parametrize("content", [b"not a torch file", b""])
def test_corrupt_or_foreign_nerf_file_is_refused_in_one_line(tmp_path, content):
    (tmp_path / "bad.pt").write_bytes(content)
    with pytest.raises(FormatError) as error:
        load_nerf(tmp_path / "bad.pt")
    assert "\n" not in str(error.value)
    torch.save({"format": "something.else"}, tmp_path / "foreign.pt")
    with pytest.raises(FormatError, match="not a fignetctl nerf file"):
        load_nerf(tmp_path / "foreign.pt")


# -- training ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return write_synthetic_scene(tmp_path_factory.mktemp("scene"))


def test_training_lowers_the_loss(scene):
    images, _, cameras = scene
    torch.manual_seed(0)
    trainer = make_trainer(images, cameras, TINY)
    trainer.run()
    losses = [h["loss"] for h in trainer.history]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:3])
    assert list(trainer.held_out_views) == [0, 4]


@pytest.mark.parametrize("background", ["learned", "black"])
def test_resume_continues_exactly(scene, tmp_path, background):
    """Also with a fixed background, where the field can empty its occupancy grid (TINY does, at
    the first refresh) and a step with no ray in occupied space has nothing to learn: it skips
    the update instead of failing."""
    images, _, cameras = scene
    config = dataclasses.replace(TINY, steps=16, occupancy_warmup=4, occupancy_every=3, background=background)
    straight = make_trainer(images, cameras, config)
    straight.run()
    first = make_trainer(images, cameras, config)
    first.run(tmp_path / "nerf.pt", until_step=7)
    resumed = make_trainer(images, cameras, config, resume_from=tmp_path / "nerf.pt")
    assert resumed.step == 7
    resumed.run()
    for a, b in zip(straight.model.state_dict().values(), resumed.model.state_dict().values()):
        assert torch.allclose(a.float(), b.float(), atol=1e-5)


def test_nan_loss_is_a_one_line_error(scene):
    images, _, cameras = scene
    trainer = make_trainer(
        images,
        cameras,
        dataclasses.replace(TINY, learning_rate_grid=float("nan"), learning_rate_mlp=float("nan")),
    )
    with pytest.raises(FignetError, match="loss became nan"):
        trainer.run()


def test_images_that_do_not_match_the_cameras_are_refused(scene, tmp_path):
    images, _, cameras = scene
    with pytest.raises(FormatError, match="not in"):
        make_trainer(tmp_path, cameras, TINY)
    smaller = dataclasses.replace(cameras, width=16, height=12)
    with pytest.raises(FormatError, match="do not match"):
        make_trainer(images, smaller, TINY)


def test_diffuse_growing_colour_grid_with_termination_resumes_and_round_trips(scene, tmp_path):
    """The fast preset's shape: no MLP, the colour grid grows with the density grid, early ray
    termination in training; a resumed run matches and the file loads at the grown sizes."""
    images, _, cameras = scene
    config = dataclasses.replace(
        TINY,
        steps=12,
        occupancy_warmup=3,
        occupancy_every=3,
        grid_resolution_initial=12,
        grid_resolution=24,
        upsample_steps=(6,),
        feature_resolution_initial=8,
        feature_resolution=16,
        feature_channels=3,
        mlp_width=0,
        transmittance_threshold=1e-3,
    )
    straight = make_trainer(images, cameras, config)
    straight.run()
    assert straight.model.field.colour_mlp is None
    assert (
        max(straight.model.field.feature_grid.shape[2:]) == 16
        and max(straight.model.field.density_grid.shape[2:]) == 24
    )
    first = make_trainer(images, cameras, config)
    first.run(tmp_path / "nerf.pt", until_step=8)
    resumed = make_trainer(images, cameras, config, resume_from=tmp_path / "nerf.pt")
    resumed.run(tmp_path / "nerf.pt")
    for a, b in zip(straight.model.state_dict().values(), resumed.model.state_dict().values()):
        assert torch.allclose(a.float(), b.float(), atol=1e-5)
    loaded = load_nerf(tmp_path / "nerf.pt")
    camera = (cameras.K[0], cameras.c2w[0], cameras.width, cameras.height)
    assert np.allclose(loaded.render(camera).rgb, resumed.model.render(camera).rgb, atol=1e-5)


# -- an environment map behind the scene box -----------------------------------------------------


def environment_model(rows=8):
    model = NerfModel(
        dataclasses.replace(TINY, background="environment", environment_resolution=rows), BOUNDS
    )
    # logits linear in the map's coordinates, which bilinear lookup reproduces exactly
    column = torch.linspace(-1.0, 1.0, 2 * rows).view(1, -1)  # azimuth / π
    row = torch.linspace(1.0, -1.0, rows).view(-1, 1)  # elevation / (π/2), the top row looks up
    with torch.no_grad():
        model.background_logit.copy_(
            torch.stack([2.0 * row + 0 * column, 1.5 * column + 0 * row, -row + 0 * column])[None]
        )
    return model


def test_environment_background_is_looked_up_by_direction():
    model = environment_model()
    directions = torch.randn(200, 3, generator=torch.Generator().manual_seed(0)) * torch.rand(200, 1) * 3
    unit = directions / directions.norm(dim=-1, keepdim=True)
    elevation = torch.asin(unit[:, 2]) / (math.pi / 2)
    azimuth = torch.atan2(unit[:, 1], unit[:, 0]) / math.pi
    expected = torch.sigmoid(torch.stack([2.0 * elevation, 1.5 * azimuth, -elevation], dim=-1))
    assert model.background(directions).detach().numpy() == pytest.approx(expected.numpy(), abs=1e-5)
    up, down = model.background(torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -2.0]])).detach()
    assert up[0] > 0.85 and down[0] < 0.15  # sigmoid(±2)


def test_environment_background_shows_where_rays_leave_the_box_and_round_trips(tmp_path):
    model = environment_model()
    with torch.no_grad():
        model.field.density_grid.fill_(-30.0)  # an empty box: every ray sees the map
    camera = (*orbit(1), 32, 24)
    camera = (camera[0][0], camera[1][0], 32, 24)
    rendering = model.render(camera)
    _, directions = pixel_rays(camera[0], camera[1], 32, 24)
    expected = model.background(torch.as_tensor(directions.reshape(-1, 3), dtype=torch.float32))
    assert rendering.rgb.reshape(-1, 3) == pytest.approx(expected.detach().numpy(), abs=1e-3)
    assert rendering.rgb.reshape(-1, 3).std(axis=0).max() > 0.01  # it varies across the image
    save_nerf(tmp_path / "nerf.pt", model)
    assert np.allclose(load_nerf(tmp_path / "nerf.pt").render(camera).rgb, rendering.rgb)


def test_training_fits_the_environment_map(scene):
    images, _, cameras = scene
    config = dataclasses.replace(TINY, background="environment", environment_resolution=4)
    trainer = make_trainer(images, cameras, config)
    trainer.run()
    # the scene's background is black: the map darkens from its initial grey
    assert torch.sigmoid(trainer.model.background_logit).mean() < 0.4
    losses = [h["loss"] for h in trainer.history]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:3])


def test_rays_start_at_the_near_distance_from_their_camera():
    origins = torch.tensor([[0.0, 0.0, -3.0], [0.0, 0.0, -0.2]])  # outside, and inside, the box
    directions = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]])
    low, high = torch.tensor([-1.0] * 3), torch.tensor([1.0] * 3)
    samples = sample_along_rays(origins, directions, low, high, 1e-2, near=0.5)
    first = samples.points[:, 0, 2]
    assert first[0].item() == pytest.approx(-1.0 + 0.005, abs=1e-6)  # the box is farther than `near`
    assert first[1].item() == pytest.approx(-0.2 + 0.5 + 0.005, abs=1e-6)  # `near` is in world units
    # a box closer than `near` to a camera inside the field is not seen by it
    _, _, opacity, _ = render_samples(ConstantBox(1e5, half=0.25), None, samples, directions, torch.zeros(3))
    assert opacity[0].item() == pytest.approx(1.0) and opacity[1].item() == 0.0


def test_a_fit_sets_near_from_the_cameras_distance(scene):
    images, _, cameras = scene
    from fignetctl.core.nerf.rays import look_at_point

    c2w = cameras.c2w
    reach = np.median(np.linalg.norm(c2w[:, :3, 3] - look_at_point(c2w), axis=1))
    trainer = make_trainer(images, cameras, dataclasses.replace(TINY, near_fraction=0.25, steps=1))
    assert (
        trainer.config.near == pytest.approx(0.25 * reach)
        and trainer.model.config.near == trainer.config.near
    )
    assert make_trainer(images, cameras, dataclasses.replace(TINY, steps=1)).config.near == 0.0


def double_sum_distortion(w, m, width):
    """Σᵢ Σⱼ wᵢ wⱼ |mᵢ − mⱼ| + ⅓ Σᵢ wᵢ² δᵢ of one ray, term by term (the reference)."""
    return (w[:, None] * w[None, :] * (m[:, None] - m[None, :]).abs()).sum() + (w**2 * width).sum() / 3


def test_distortion_equals_its_double_sum_and_prefers_one_surface():
    generator = torch.Generator().manual_seed(0)
    weights = torch.rand(6, 9, generator=generator) / 9
    t = torch.sort(torch.rand(6, 9, generator=generator) * 3, dim=1).values
    step = torch.rand(6, 9, generator=generator) * 0.1
    fast = distortion(weights, t, step, scale=2.0)
    for row in range(6):
        brute = double_sum_distortion(weights[row], t[row] / 2.0, step[row] / 2.0)
        assert fast[row].item() == pytest.approx(brute.item(), rel=1e-5)
    # the same opacity on one sample, on two neighbours, and split between surfaces 1 apart
    t = torch.arange(10.0)[None].expand(3, -1) * 0.1
    weights = torch.zeros(3, 10)
    weights[0, 2], weights[1, 2:4], weights[2, [2, 9]] = 0.8, 0.4, 0.4
    one, near, split = distortion(weights, t, torch.full((3,), 0.1)).tolist()
    assert one < near < split
    assert split == pytest.approx(2 * 0.4 * 0.4 * 0.7 + 2 * 0.4**2 * 0.1 / 3)


def test_render_rays_reports_distortion_in_scene_box_units():
    """A ray through a constant-density box: distortion from the model's own samples equals the
    double sum over them, with distances divided by the scene box's longest side (2)."""
    model = solid_box_model(dataclasses.replace(TINY, background="black"), raw=0.0)
    origins, directions = torch.tensor([[0.0, 0.0, -3.0]]), torch.tensor([[0.0, 0.0, 2.0]])
    out = model.render_rays(origins, directions, skip_empty=False, with_distortion=True)
    samples = sample_along_rays(
        origins, directions, model.field.bounds[0], model.field.bounds[1], model.step_length
    )
    _, _, _, weights = render_samples(model.field, None, samples, directions, torch.zeros(3))
    distance = samples.t[0] * 2.0  # ray parameter × |d|
    brute = double_sum_distortion(weights[0], distance / 2.0, samples.step[0] / 2.0)
    assert out["distortion"].item() == pytest.approx(brute.item(), rel=1e-4) and brute > 0
    assert "distortion" not in model.render_rays(origins, directions)


def test_training_adds_the_weighted_distortion_to_the_loss(scene):
    images, _, cameras = scene
    excess = {}
    for weight in (0.0, 10.0):
        trainer = make_trainer(images, cameras, dataclasses.replace(TINY, steps=1, distortion_weight=weight))
        trainer.run()
        record = trainer.history[0]
        excess[weight] = record["loss"] - 10 ** (-record["psnr"] / 10)  # loss beyond the colour MSE
    assert excess[0.0] == pytest.approx(0.0, abs=1e-9)
    assert excess[10.0] > 1e-6, excess


def test_auto_background_and_near_follow_the_share_of_points_outside_the_box():
    """`for_capture`: 'auto' and None become the room settings from a fifth of the sparse points
    outside the scene box on, and the plain ones below it; values set are kept either way."""
    from fignetctl.core.nerf.config import ROOM_NEAR, ROOM_POINTS, for_capture

    auto = NerfConfig(background="auto", near_fraction=None)
    bounds = np.array([[-1.0] * 3, [1.0] * 3])
    for outside in (0, 19, 20, 60):
        points = np.concatenate([np.zeros((100 - outside, 3)), np.full((outside, 3), 5.0)])
        config, capture = for_capture(auto, points, bounds)
        room = outside / 100 >= ROOM_POINTS
        assert capture.outside == pytest.approx(outside / 100) and capture.room == room
        assert (config.background, config.near_fraction) == (
            ("environment", ROOM_NEAR) if room else ("learned", 0.0)
        )
        kept, _ = for_capture(NerfConfig(background="white", near_fraction=0.1), points, bounds)
        assert (kept.background, kept.near_fraction) == ("white", 0.1)
    assert for_capture(auto, np.zeros((0, 3)), bounds)[0].background == "learned"
