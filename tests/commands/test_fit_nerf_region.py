"""fit-nerf --region through the CLI on a tiny synthetic scene: the printed line and --json
report the region's voxel size beside PSNR and the region's PSNR; bad regions are one-line
errors."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.nerf.io import load_nerf
from tests.commands.test_fit_nerf import one_line_error
from tests.core.test_nerf import write_synthetic_scene
from tests.core.test_nerf_region import write_prompts

FAST = ["--max-image-side", "32", "--rays-per-batch", "128", "--steps", "3"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("region")
    images, cameras, camera_set = write_synthetic_scene(folder)
    prompts = write_prompts(folder / "prompts.json", camera_set, {"box": (0.1, 0.0, 0.1)})
    return folder, images, cameras, prompts


def fit(images, cameras, output, *extra):
    return CliRunner().invoke(
        cli, ["fit-nerf", str(images), str(cameras), "-o", str(output), *FAST, *map(str, extra)]
    )


def test_a_box_region_is_fitted_finely_and_reported(scene, tmp_path):
    _, images, cameras, _ = scene
    nerf, summary = tmp_path / "nerf.pt", tmp_path / "fit.json"
    result = fit(images, cameras, nerf, "--region", "-0.5,-0.5,-0.5,0.5,0.5,0.5", "--json", summary)
    assert result.exit_code == 0, result.output
    line = result.stderr.strip().splitlines()[-1]
    assert "region PSNR" in line and "voxel" in line and "in the 1.00 x 1.00 x 1.00 m region" in line, line
    metrics = json.loads(summary.read_text())
    model = load_nerf(nerf)
    assert np.array(metrics["region"]) == pytest.approx(model.region, abs=1e-6)
    assert metrics["voxel_size"] == pytest.approx(1.0 / (64 - 1), rel=1e-4)  # the fast preset at step 3
    assert metrics["background_voxel_size"] > metrics["voxel_size"]
    assert np.isfinite(metrics["held_out_region_psnr"])


def test_region_rays_are_kept_in_the_file_and_out_of_range_is_refused(scene, tmp_path):
    _, images, cameras, _ = scene
    box = "-0.2,-0.2,-0.2,0.2,0.2,0.2"
    result = fit(images, cameras, tmp_path / "r.pt", "--region", box, "--region-rays", "0.5")
    assert result.exit_code == 0, result.output
    assert load_nerf(tmp_path / "r.pt").config.region_rays == 0.5
    assert "--region-rays" in one_line_error(
        fit(images, cameras, tmp_path / "bad.pt", "--region-rays", "1.5")
    )


def test_auto_with_prompts_fits_around_them_and_scene_prints_its_voxel(scene, tmp_path):
    _, images, cameras, prompts = scene
    result = fit(images, cameras, tmp_path / "a.pt", "--prompts", prompts, "--region-margin", "0.3")
    assert result.exit_code == 0, result.output
    region = load_nerf(tmp_path / "a.pt").region
    assert region == pytest.approx(np.array([[-0.2, -0.3, -0.2], [0.4, 0.3, 0.4]]), abs=0.1)
    result = fit(images, cameras, tmp_path / "s.pt", "--prompts", prompts, "--region", "scene")
    assert result.exit_code == 0, result.output
    assert load_nerf(tmp_path / "s.pt").region is None
    assert "voxel" in result.stderr and "region PSNR" not in result.stderr


@pytest.mark.parametrize(
    "extra, code, message",
    [
        (["--region", "5,5,5,6,6,6"], 1, "lies outside the scene box"),
        (["--region", "room"], 2, "give one of auto, scene, prompts"),
        (["--region", "prompts"], 2, "needs --prompts"),
        (["--region", "support:-1"], 2, "positive height"),
        (["--region", "prompts", "--prompts", "missing.json"], 1, "no such prompts file"),
    ],
)
def test_bad_regions_are_one_line_errors(scene, tmp_path, extra, code, message):
    _, images, cameras, _ = scene
    result = fit(images, cameras, tmp_path / "n.pt", *extra)
    assert result.exit_code == code, result.output
    assert message in one_line_error(result)
    assert not (tmp_path / "n.pt").exists()
