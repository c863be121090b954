"""fit-nerf's region: fine grids in a box with a coarse grid elsewhere. The fine grid answers
inside the region at its voxel size, sampling across the region's faces composites exactly,
the region is found from prompts and the support plane, bad regions are one-line errors, and
nerf.pt keeps the region (while files without one load as before). Tiny scenes; seconds."""

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from fignetctl.core.nerf.io import FORMAT_VERSION, load_nerf, read_nerf_payload, save_nerf
from fignetctl.core.nerf.model import NerfModel
from fignetctl.core.nerf.region import (
    check_seen,
    parse_region,
    prompts_box,
    resolve_region,
    support_box,
)
from fignetctl.core.nerf.renderer import RegionSteps, render_samples, sample_along_rays
from fignetctl.core.nerf.training import finish, make_trainer
from fignetctl.core.pinhole import project
from fignetctl.errors import FignetError, FormatError, SettingError
from tests.core.test_nerf import BOUNDS, TINY, write_synthetic_scene

REGION = np.array([[-0.3, -0.2, -0.25], [0.3, 0.4, 0.25]])


def region_model(config=TINY, region=REGION, resolution=None):
    with torch.random.fork_rng():
        torch.manual_seed(0)
        return NerfModel(
            config, BOUNDS, density_resolution=resolution or config.grid_resolution, region=region
        )


def set_constant_density(model, sigma):
    """Raw values that give density `sigma` everywhere, on both levels."""
    with torch.no_grad():
        for level, grid in enumerate(model.field.density_grids()):
            scaled = sigma * model.field.reference_voxels()[level]
            grid.fill_(math.log(math.expm1(scaled)) - model.field.density_shift)
    model.refresh_occupancy()


def test_points_in_the_region_get_the_fine_grid_and_its_voxel_size():
    model = region_model()
    field = model.field
    fine, coarse = field.region_voxel_size, field.voxel_size
    region_extent = (REGION[1] - REGION[0]).max()
    assert fine == pytest.approx(region_extent / (TINY.grid_resolution - 1), rel=1e-5)
    assert coarse == pytest.approx(
        2.0 / (round(TINY.grid_resolution * TINY.background_fraction) - 1), rel=1e-5
    )
    assert model.voxel_size == fine < coarse / 2
    # a value per fine vertex: the field returns it at the fine vertices, and the coarse grid outside
    with torch.no_grad():
        field.region_density_grid.copy_(torch.randn_like(field.region_density_grid) * 3)
        field.density_grid.fill_(-5.0)
    shape = field.region_density_grid.shape[2:]
    axes = [np.linspace(REGION[0][i], REGION[1][i], shape[i]) for i in range(3)]  # vertices on the faces
    index = np.array([[1, 2, 3], [5, 0, 7], [shape[0] - 2, shape[1] - 1, 4]])
    points = np.array([[axes[i][j] for i, j in enumerate(row)] for row in index])
    expected = field.raw_to_density(field.region_density_grid[0, 0][tuple(index.T)], level=1)
    assert model.density(points) == pytest.approx(expected.detach().numpy(), rel=1e-3)
    outside = np.array([[0.8, 0.8, 0.8], [-0.9, 0.0, 0.0]])
    background = field.raw_to_density(torch.tensor(-5.0), level=0).item()
    assert model.density(outside) == pytest.approx([background] * 2, rel=1e-4)


def test_region_sampling_is_fine_inside_and_composites_a_constant_density_exactly():
    model = region_model()
    sigma = 0.7
    set_constant_density(model, sigma)
    origins = torch.tensor([[0.0, 0.1, -3.0], [0.9, 0.9, -3.0], [-2.0, 0.05, 0.1]])
    directions = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [1.0, 0.1, 0.0]])
    steps = model.step_length
    assert isinstance(steps, RegionSteps) and float(steps) == pytest.approx(0.5 * model.field.voxel_size)
    low, high = model.field.bounds
    samples = sample_along_rays(origins, directions, low, high, steps)
    t, valid, step = samples.t, samples.valid, samples.step
    for ray in range(3):
        ts = t[ray][valid[ray]]
        assert (ts[1:] >= ts[:-1]).all()  # in order along the ray
    # the first ray crosses the region for z in [-0.25, 0.25]: fine steps there
    inside = valid[0] & (samples.points[0, :, 2].abs() < 0.24)
    assert (step[0][inside] <= steps.fine + 1e-6).all() and (step[0][inside] > 0.9 * steps.fine).all()
    assert (step[0][valid[0] & ~inside] > steps.fine).any()
    # each ray's steps add up to its chord through the scene box (2 units; the third ray 2 along x)
    chords = [2.0, 2.0, math.sqrt(2.0**2 + 0.2**2)]
    for ray in range(3):
        assert float(step[ray][valid[ray]].sum()) == pytest.approx(chords[ray], rel=1e-5)
    with torch.no_grad():
        _, depth, opacity, _ = render_samples(
            model.field, model.occupancy, samples, directions, torch.zeros(3)
        )
    exact = [1 - math.exp(-sigma * c) for c in chords]
    assert opacity.numpy() == pytest.approx(exact, abs=2e-3)
    # the expected distance along a constant medium of length L entered at a
    exact_depth = 2.0 + 1 / sigma - 2.0 * math.exp(-2 * sigma) / (1 - math.exp(-2 * sigma))
    assert depth[0].item() == pytest.approx(exact_depth, abs=5e-3)


def test_region_step_ratio_spaces_the_samples_in_the_region_alone():
    plain, wide = region_model(), region_model(dataclasses.replace(TINY, region_step_ratio=1.0))
    fine = plain.field.region_voxel_size
    assert plain.step_length.fine == pytest.approx(TINY.step_ratio * fine)  # 0: step_ratio
    assert wide.step_length.fine == pytest.approx(fine)
    assert float(wide.step_length) == float(plain.step_length)  # outside the region: unchanged
    set_constant_density(wide, 0.7)
    origins, directions = torch.tensor([[0.0, 0.1, -3.0]]), torch.tensor([[0.0, 0.0, 1.0]])
    samples = sample_along_rays(origins, directions, *wide.field.bounds, wide.step_length)
    with torch.no_grad():
        _, _, opacity, _ = render_samples(wide.field, wide.occupancy, samples, directions, torch.zeros(3))
    assert opacity.item() == pytest.approx(1 - math.exp(-0.7 * 2.0), abs=2e-3)
    counts = [
        int(sample_along_rays(origins, directions, *m.field.bounds, m.step_length).valid.sum())
        for m in (plain, wide)
    ]
    in_region = 0.5 / fine  # the ray crosses the region for z in [-0.25, 0.25]
    assert counts[0] - counts[1] == pytest.approx(in_region, abs=2)


class _SearchingField:
    """A region field without `level_order`: each of its queries finds its points' levels itself."""

    def __init__(self, field):
        self.field = field

    def density(self, points):
        return self.field.density(points)

    def colour(self, points, directions):
        return self.field.colour(points, directions)


class _SearchingOccupancy:
    def __init__(self, occupancy):
        self.occupancy = occupancy

    def lookup(self, points):
        return self.occupancy.lookup(points)


def test_rendering_with_samples_in_level_order_matches_searching_each_query():
    model = region_model()
    with torch.no_grad():
        for grid in model.field.density_grids():
            grid.copy_(torch.randn_like(grid) * 2 + 4)
        for grid in model.field.feature_grids():
            grid.copy_(torch.randn_like(grid))
        model.field.region_density_grid[0, 0, : TINY.grid_resolution // 2] = -20.0  # empty space to skip
    model.refresh_occupancy()
    generator = torch.Generator().manual_seed(3)
    origins = torch.randn(64, 3, generator=generator) * 0.2 + torch.tensor([0.0, 0.0, -3.0])
    directions = torch.randn(64, 3, generator=generator) * 0.3 + torch.tensor([0.0, 0.0, 1.0])
    samples = sample_along_rays(origins, directions, *model.field.bounds, model.step_length)
    results = []
    for field, occupancy in (
        (model.field, model.occupancy),
        (_SearchingField(model.field), _SearchingOccupancy(model.occupancy)),
    ):
        model.zero_grad()
        rgb, depth, opacity, _ = render_samples(
            field, occupancy, samples, directions, torch.zeros(3), None, 1e-4, 0.3
        )
        (rgb.sum() + depth.sum()).backward()
        grads = [grid.grad.clone() for grid in [*model.field.density_grids(), *model.field.feature_grids()]]
        results.append((rgb.detach(), depth.detach(), opacity.detach(), grads))
    (rgb, depth, opacity, grads), (rgb2, depth2, opacity2, grads2) = results
    assert 0.05 < float(opacity.mean()) < 0.999  # neither empty nor opaque at the first sample
    assert torch.equal(rgb, rgb2) and torch.equal(depth, depth2) and torch.equal(opacity, opacity2)
    for grad, grad2 in zip(grads, grads2):
        assert grad.abs().sum() > 0
        torch.testing.assert_close(grad, grad2)


def test_region_grid_is_capped_at_max_vertices():
    config = dataclasses.replace(TINY, grid_resolution=64, region_max_vertices=20_000)
    model = region_model(config, resolution=64)
    assert model.field.region_density_grid[0, 0].numel() <= 20_000
    assert model.field.region_voxel_size < model.field.voxel_size


def test_nerf_pt_round_trip_keeps_the_region(tmp_path):
    model = region_model()
    with torch.no_grad():
        for grid in (*model.field.density_grids(), *model.field.feature_grids()):
            grid.copy_(torch.randn_like(grid))
    model.refresh_occupancy()
    save_nerf(tmp_path / "nerf.pt", model, metrics={"voxel_size": model.voxel_size})
    payload = read_nerf_payload(tmp_path / "nerf.pt")
    assert payload["format_version"] == FORMAT_VERSION == 2
    loaded = load_nerf(tmp_path / "nerf.pt")
    assert loaded.region == pytest.approx(REGION, abs=1e-6)
    assert loaded.voxel_size == pytest.approx(model.voxel_size)
    points = np.random.default_rng(0).uniform(-1, 1, (500, 3))
    assert loaded.density(points) == pytest.approx(model.eval().density(points), rel=1e-5)
    assert torch.equal(loaded.occupancy.region_occupied, model.occupancy.region_occupied)


def test_nerf_pt_without_a_region_is_version_1_and_old_files_still_load(tmp_path):
    model = NerfModel(TINY, BOUNDS, density_resolution=TINY.grid_resolution)
    save_nerf(tmp_path / "nerf.pt", model)
    payload = torch.load(tmp_path / "nerf.pt", weights_only=True)
    assert payload["format_version"] == 1 and "region" not in payload
    # a file written before regions existed: its config lacks the region's fields
    config = json.loads(payload["config"])
    del config["background_fraction"], config["region_max_vertices"]
    payload["config"] = json.dumps(config)
    torch.save(payload, tmp_path / "old.pt")
    old = load_nerf(tmp_path / "old.pt")
    assert old.region is None and not old.field.has_region
    assert old.voxel_size == pytest.approx(2.0 / (TINY.grid_resolution - 1))
    assert isinstance(old.step_length, float) and not isinstance(old.step_length, RegionSteps)
    payload["format_version"] = 3
    torch.save(payload, tmp_path / "future.pt")
    with pytest.raises(FormatError, match="format_version 3 is not supported .*reads 1 or 2"):
        load_nerf(tmp_path / "future.pt")


def test_a_region_outside_the_bounds_of_a_file_is_refused(tmp_path):
    save_nerf(tmp_path / "nerf.pt", region_model())
    payload = torch.load(tmp_path / "nerf.pt", weights_only=True)
    payload["region"] = [[0.5, 0.5, 0.5], [3.0, 3.0, 3.0]]
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(FormatError, match="not inside bounds"):
        load_nerf(tmp_path / "bad.pt")


@pytest.mark.parametrize(
    "text, message",
    [
        ("room", "give one of"),
        ("1,2,3", "give one of"),
        ("0,0,0,1,1,nan", "give one of"),
        ("0,0,0,1,-1,1", "must exceed"),
        ("support:0", "positive height"),
        ("support:x", "positive height"),
        ("prompts", "needs `prompts`"),
    ],
)
def test_bad_region_text_is_a_setting_error(text, message):
    with pytest.raises(SettingError, match=message):
        parse_region(text)


def test_auto_is_prompts_with_a_prompts_file_else_the_scene():
    assert parse_region("auto").kind == "scene"
    assert parse_region("auto", prompts="p.json").kind == "prompts"
    assert parse_region("support:0.3").height == 0.3
    assert parse_region("-1,-1,0,1,1,0.5").box == (-1, -1, 0, 1, 1, 0.5)


def test_regions_outside_the_scene_or_unseen_are_one_line_errors(tmp_path):
    _, _, cameras = write_synthetic_scene(tmp_path)
    with pytest.raises(FignetError, match="lies outside the scene box") as error:
        resolve_region(parse_region("5,5,5,6,6,6"), cameras, BOUNDS)
    assert "\n" not in str(error.value)
    with pytest.raises(FignetError, match="is thinner than"):
        resolve_region(parse_region("-0.2,-0.2,0,0.2,0.2,1e-9"), cameras, BOUNDS)
    box = resolve_region(parse_region("-0.2,-0.2,-0.2,0.2,0.2,5"), cameras, BOUNDS)
    assert box == pytest.approx(np.array([[-0.2, -0.2, -0.2], [0.2, 0.2, 1.0]]))  # clipped
    check_seen(box, cameras, range(len(cameras)))
    behind = np.array([[-0.1, -0.1, 5.0], [0.1, 0.1, 5.2]])  # above every camera, out of view
    with pytest.raises(FignetError, match="is seen by 0 of the 8 training views"):
        check_seen(behind, cameras, range(len(cameras)))


def write_prompts(path, cameras, objects):
    """prompts.json with each object's centre projected into three views."""
    entries = []
    for name, centre in objects.items():
        points = []
        for view in (0, 3, 5):
            image, _ = project(cameras.K[view], cameras.c2w[view], np.array([centre]))
            u, v = np.floor(image[0]).astype(int)
            points.append({"image": str(cameras.image_names[view]), "u": int(u), "v": int(v)})
        entries.append({"id": len(entries), "name": name, "points": points})
    path.write_text(json.dumps({"format": "fignetctl.prompts", "format_version": 1, "objects": entries}))
    return path


def test_prompts_region_holds_a_cube_around_each_prompted_object(tmp_path):
    _, _, cameras = write_synthetic_scene(tmp_path, width=64, height=48)
    objects = {"a": (0.2, 0.1, 0.0), "b": (-0.1, -0.2, 0.1)}
    prompts = write_prompts(tmp_path / "prompts.json", cameras, objects)
    box = prompts_box(prompts, cameras, margin=0.15)
    centres = np.array(list(objects.values()))
    pixel = 3.0 / 30.0  # a pixel at the cameras' distance
    assert box[0] == pytest.approx(centres.min(0) - 0.15, abs=pixel)
    assert box[1] == pytest.approx(centres.max(0) + 0.15, abs=pixel)
    region = resolve_region(parse_region("auto", prompts=prompts, margin=0.15), cameras, BOUNDS)
    assert region == pytest.approx(box)


def test_a_prompted_objects_cube_grows_with_its_inscribed_radius(tmp_path):
    """With `inscribed_radius_px`, an object's cube is at least INSCRIBED_RADII of those radii
    (at the object's depth in each view, the largest) in half-size; a small radius leaves the
    margin."""
    from fignetctl.core.nerf.region import INSCRIBED_RADII

    _, _, cameras = write_synthetic_scene(tmp_path, width=64, height=48)
    centre = np.array([0.1, 0.0, 0.05])
    prompts = write_prompts(tmp_path / "prompts.json", cameras, {"a": tuple(centre)})
    document = json.loads(prompts.read_text())
    for point, radius in zip(document["objects"][0]["points"], (4.0, 6.0, 5.0)):
        point["inscribed_radius_px"] = radius
    prompts.write_text(json.dumps(document))
    half = 0.0
    for view, radius in zip((0, 3, 5), (4.0, 6.0, 5.0)):
        depth = (np.linalg.inv(cameras.c2w[view]) @ [*centre, 1.0])[2]
        half = max(
            half, INSCRIBED_RADII * radius * depth / np.sqrt(cameras.K[view][0, 0] * cameras.K[view][1, 1])
        )
    assert half > 0.05
    box = prompts_box(prompts, cameras, margin=0.05)
    pixel = 3.0 / 30.0
    assert box[1] - box[0] == pytest.approx([2 * half] * 3, abs=pixel)
    assert box.mean(axis=0) == pytest.approx(centre, abs=pixel)
    larger = prompts_box(prompts, cameras, margin=2 * half)  # the margin wins over the radii
    assert larger[1] - larger[0] == pytest.approx([4 * half] * 3, abs=pixel)


def test_prompts_that_do_not_meet_are_refused(tmp_path):
    _, _, cameras = write_synthetic_scene(tmp_path, width=64, height=48)
    prompts = write_prompts(tmp_path / "prompts.json", cameras, {"a": (0.0, 0.0, 0.0)})
    document = json.loads(prompts.read_text())
    document["objects"][0]["points"][1].update(u=0, v=0)  # another object in the second view
    prompts.write_text(json.dumps(document))
    with pytest.raises(FignetError, match="prompt rays of 'a' pass .* from their common point"):
        prompts_box(prompts, cameras, margin=0.05)
    prompts.write_text("{}")
    with pytest.raises(FormatError, match="not a usable prompts.json"):
        prompts_box(prompts, cameras, margin=0.05)


def test_support_region_spans_the_plane_points():
    from fignetctl.core.cameras import Cameras

    rng = np.random.default_rng(0)
    plane = np.c_[rng.uniform(-0.5, 0.7, (400, 2)), np.zeros(400)]
    above = rng.uniform(-0.2, 0.2, (100, 3)) + [0, 0, 0.5]
    cameras = Cameras(np.array(["a"]), np.eye(3)[None], np.eye(4)[None], 8, 8, np.r_[plane, above])
    box = support_box(cameras, BOUNDS, 0.3)
    assert box[0] == pytest.approx([-0.5, -0.5, -0.03], abs=0.03)
    assert box[1] == pytest.approx([0.7, 0.7, 0.3], abs=0.03)
    cameras.points = above
    with pytest.raises(FignetError, match="sparse points lie on the support plane"):
        support_box(cameras, BOUNDS, 0.3)


def test_a_region_fit_lowers_the_loss_and_reports_region_psnr(tmp_path):
    images, _, cameras = write_synthetic_scene(tmp_path)
    config = dataclasses.replace(TINY, steps=40, rays_per_batch=512)
    trainer = make_trainer(images, cameras, config, region=np.array([[-0.6] * 3, [0.6] * 3]))
    trainer.run()
    losses = [r["loss"] for r in trainer.history]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])
    metrics, _ = finish(trainer, tmp_path / "nerf.pt")
    assert np.array(metrics["region"]) == pytest.approx(np.array([[-0.6] * 3, [0.6] * 3]))
    assert metrics["voxel_size"] == pytest.approx(1.2 / (TINY.grid_resolution - 1), rel=1e-5)
    assert metrics["background_voxel_size"] > metrics["voxel_size"]
    assert np.isfinite(metrics["held_out_region_psnr"])
    assert all(0 < v["region_pixels"] < 1 for v in metrics["held_out"])
    assert load_nerf(tmp_path / "nerf.pt").region is not None


def test_rays_through_the_region_are_found_by_the_slab_test_and_fill_their_share_of_a_batch(tmp_path):
    """`rays_through_region` holds exactly the rays that have a point inside the region (dense
    points along each ray, brute force), and with `region_rays` 0.75 at least that share of a
    batch passes through it; with 0 the batch is what it was (the same random draws)."""
    from fignetctl.core.nerf.rays import ray_box_intersection
    from fignetctl.core.nerf.training import rays_through_region

    model = region_model()
    rng = np.random.default_rng(0)
    origins = torch.as_tensor(rng.uniform(-2, 2, (400, 3)), dtype=torch.float32)
    directions = torch.as_tensor(rng.normal(size=(400, 3)), dtype=torch.float32)
    found = set(rays_through_region(model, origins, directions).tolist())
    t = torch.linspace(0, 8, 4001)
    points = origins[:, None, :] + t[None, :, None] * directions[:, None, :]
    low, high = torch.as_tensor(REGION[0]), torch.as_tensor(REGION[1])
    inside = ((points >= low) & (points <= high)).all(-1).any(-1)
    near, far = ray_box_intersection(origins, directions, low.float(), high.float())
    grazing = (far - near).abs() < 0.01  # a chord shorter than the brute force's step may be missed
    expected = set(torch.nonzero(inside).reshape(-1).tolist())
    assert {i for i in found ^ expected if not grazing[i]} == set()
    assert 0 < len(found) < 400
    assert rays_through_region(NerfModel(TINY, BOUNDS, density_resolution=8), origins, directions) is None

    images, _, cameras = write_synthetic_scene(tmp_path)
    box = np.array([[-0.1] * 3, [0.1] * 3])
    focused = make_trainer(images, cameras, dataclasses.replace(TINY, region_rays=0.75), region=box)
    through = set(focused.through_region.tolist())
    assert 0 < len(through) < 0.5 * len(focused.origins)
    batch = focused._ray_batch().tolist()
    assert sum(i in through for i in batch) >= 0.75 * len(batch)
    plain = make_trainer(images, cameras, TINY, region=box)
    expected = torch.randint(
        len(plain.origins), (TINY.rays_per_batch,), generator=torch.Generator().manual_seed(TINY.seed)
    )
    assert torch.equal(plain._ray_batch(), expected)
