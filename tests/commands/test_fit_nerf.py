"""fit-nerf and render-nerf through the CLI on a tiny synthetic scene: outputs, resume, and
one-line errors for bad input."""

import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.cameras import read_cameras, write_cameras
from fignetctl.core.nerf.io import load_nerf
from tests.core.test_nerf import write_synthetic_scene

FAST = ["--max-image-side", "32", "--rays-per-batch", "128"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fit")
    images, cameras, _ = write_synthetic_scene(folder)
    nerf = folder / "nerf.pt"
    result = CliRunner().invoke(
        cli,
        [
            "fit-nerf",
            str(images),
            str(cameras),
            "-o",
            str(nerf),
            "--steps",
            "3",
            *FAST,
            "--rerun",
            str(folder / "fit.rrd"),
        ],
    )
    assert result.exit_code == 0, result.output
    return folder, images, cameras, nerf, result


def test_fit_writes_a_loadable_field_with_metrics_and_a_rerun_log(fitted):
    folder, _, _, nerf, result = fitted
    assert result.stdout.strip().endswith(str(nerf))
    model = load_nerf(nerf)
    assert model.metrics["steps"] == 3 and np.isfinite(model.metrics["held_out_psnr"])
    assert model.inputs["held_out_views"] == [0] and model.inputs["trained_width"] == 32
    assert (folder / "fit.rrd").stat().st_size > 0


def test_existing_output_needs_overwrite_and_resume_continues(fitted):
    _, images, cameras, nerf, _ = fitted
    result = CliRunner().invoke(
        cli, ["fit-nerf", str(images), str(cameras), "-o", str(nerf), "--steps", "5", *FAST]
    )
    assert result.exit_code == 2 and "--overwrite" in result.output
    result = CliRunner().invoke(
        cli, ["fit-nerf", str(images), str(cameras), "-o", str(nerf), "--steps", "5", "--resume", *FAST]
    )
    assert result.exit_code == 0, result.output
    assert load_nerf(nerf).metrics["steps"] == 5


def test_render_nerf_writes_colour_and_depth(fitted, tmp_path):
    _, _, cameras, nerf, _ = fitted
    out = tmp_path / "renders"
    result = CliRunner().invoke(
        cli, ["render-nerf", str(nerf), str(cameras), "-o", str(out), "--views", "0,3"]
    )
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == [
        "view_000.png",
        "view_000_depth.npy",
        "view_000_depth.png",
        "view_003.png",
        "view_003_depth.npy",
        "view_003_depth.png",
    ]
    assert np.load(out / "view_000_depth.npy").shape == (24, 32)


def _one_line_error(result):
    assert result.exit_code != 0 and isinstance(result.exception, SystemExit), result.exception
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    return errors[0]


def test_bad_inputs_are_one_line_errors(fitted, tmp_path):
    _, images, cameras, nerf, _ = fitted
    runner = CliRunner()
    out = str(tmp_path / "n.pt")
    message = _one_line_error(runner.invoke(cli, ["fit-nerf", str(tmp_path), str(cameras), "-o", out, *FAST]))
    assert "not in" in message
    shrunk = read_cameras(cameras)
    shrunk.width, shrunk.height = 16, 12
    write_cameras(tmp_path / "small.npz", shrunk)
    message = _one_line_error(
        runner.invoke(cli, ["fit-nerf", str(images), str(tmp_path / "small.npz"), "-o", out, *FAST])
    )
    assert "do not match" in message
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "view_000.png").write_bytes(b"not a png")
    message = _one_line_error(
        runner.invoke(cli, ["fit-nerf", str(tmp_path / "images"), str(cameras), "-o", out, *FAST])
    )
    assert "view_00" in message
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    message = _one_line_error(
        runner.invoke(cli, ["render-nerf", str(tmp_path / "bad.pt"), str(cameras), "-o", str(tmp_path / "r")])
    )
    assert "not a readable nerf.pt" in message
    message = _one_line_error(
        runner.invoke(
            cli, ["render-nerf", str(nerf), str(cameras), "-o", str(tmp_path / "r"), "--views", "99"]
        )
    )
    assert "--views" in message
