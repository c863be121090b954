"""fit-nerf and render-nerf through the CLI on a tiny synthetic scene: outputs, resume, and
one-line errors for bad input."""

import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.cameras import read_cameras, write_cameras
from fignetctl.core.nerf.io import load_nerf
from tests.core.test_nerf import write_synthetic_scene
from tests.rerun_reading import SavingViewer, dead_address, read_recording, rerun_executable

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
    recording = read_recording(folder / "fit.rrd")
    for curve in ("fit-nerf/loss", "fit-nerf/train_psnr"):
        assert recording.times(curve, "step") == [1, 2, 3] and recording.rows(curve) == 3
    views = ["fit-nerf/held_out/view_000/" + name for name in ("depth", "image", "rendered")]
    assert recording.entities_under("fit-nerf/held_out") == views
    assert all(recording.times(view, "step") == [3] for view in views)
    assert recording.recording_id == str(folder.resolve())


@pytest.mark.skipif(rerun_executable() is None, reason="the rerun viewer CLI is not installed")
def test_fit_streams_to_a_running_viewer_what_it_records(fitted, tmp_path):
    _, images, cameras, _, _ = fitted
    rrd = tmp_path / "fit.rrd"
    with SavingViewer(tmp_path / "viewer" / "live.rrd") as viewer:
        result = fit(images, cameras, tmp_path / "nerf.pt", "--rerun", rrd, "--rerun-connect", viewer.address)
        assert result.exit_code == 0, result.output
    live, saved = read_recording(viewer.path), read_recording(rrd)
    assert sorted(live.entities) == sorted(saved.entities)  # the curves step by step, then the views
    for entity in saved.entities:
        assert live.times(entity, "step") == saved.times(entity, "step"), entity
    assert live.recording_id == saved.recording_id == str(tmp_path.resolve())


def test_fit_goes_on_when_no_viewer_listens(fitted, tmp_path):
    _, images, cameras, _, _ = fitted
    address = dead_address()
    result = fit(images, cameras, tmp_path / "nerf.pt", "--rerun-connect", address)
    assert result.exit_code == 0, result.output
    assert [line for line in result.stderr.splitlines() if "warning" in line] == [
        f"warning: no rerun viewer listens at {address}; going on without live viewing"
    ]
    assert load_nerf(tmp_path / "nerf.pt").metrics["steps"] == 3


def fit(images, cameras, output, *extra):
    return CliRunner().invoke(
        cli,
        ["fit-nerf", str(images), str(cameras), "-o", str(output), "--steps", "3", *FAST, *map(str, extra)],
    )


def test_background_near_and_distortion_reach_the_fit_and_a_resumed_run_keeps_them(fitted, tmp_path):
    _, images, cameras, _, _ = fitted
    nerf = tmp_path / "nerf.pt"
    result = fit(
        images, cameras, nerf, "--background", "environment", "--near", "0.2", "--distortion", "0.03"
    )
    assert result.exit_code == 0, result.output
    config = load_nerf(nerf).config
    assert config.background == "environment" and config.near_fraction == 0.2 and config.near > 0
    assert config.distortion_weight == 0.03
    resumed = fit(images, cameras, nerf, "--resume", "--steps", "4")
    assert resumed.exit_code == 0, resumed.output
    again = load_nerf(nerf).config
    assert (again.near, again.background, again.distortion_weight) == (config.near, "environment", 0.03)
    for flag, value in (("--near", "2"), ("--distortion", "-1")):
        bad = fit(images, cameras, tmp_path / "other.pt", flag, value)
        assert bad.exit_code == 2 and flag in bad.output


def test_a_capture_in_a_room_gets_the_environment_and_near_and_says_so(fitted, tmp_path):
    """The preset's 'auto' background and near: a capture whose sparse points stay in the scene
    box keeps one learned colour and rays from the box; one with walls beyond the box (a fifth
    of its points or more outside it) gets the environment map and near 0.2, with a line on
    stderr; flags given are kept."""
    _, images, cameras, nerf, result = fitted
    plain = load_nerf(nerf).config
    assert (plain.background, plain.near_fraction, plain.near) == ("learned", 0.0, 0.0)
    assert "room" not in result.stderr
    room = read_cameras(cameras)
    angles = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    far = 10 * np.abs(room.c2w[:, :3, 3]).max()
    walls = np.stack([far * np.cos(angles), far * np.sin(angles), np.zeros(60)], 1)
    room.points = np.concatenate([room.points, walls])
    room.point_colors = np.zeros((len(room.points), 3), np.uint8)
    write_cameras(tmp_path / "room.npz", room)
    result = fit(images, tmp_path / "room.npz", tmp_path / "room.pt")
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stderr.splitlines() if "room" in line]
    assert len(lines) == 1 and lines[0].endswith(
        "% of the sparse points lie outside the scene box, a capture in a room: background "
        "environment, near 0.2 (--background, --near to choose)"
    ), result.stderr
    config = load_nerf(tmp_path / "room.pt").config
    assert config.background == "environment" and config.near_fraction == 0.2 and config.near > 0
    chosen = fit(
        images, tmp_path / "room.npz", tmp_path / "chosen.pt", "--background", "learned", "--near", "0"
    )
    assert chosen.exit_code == 0 and "room" not in chosen.stderr, chosen.output
    config = load_nerf(tmp_path / "chosen.pt").config
    assert (config.background, config.near_fraction, config.near) == ("learned", 0.0, 0.0)


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


def one_line_error(result):
    """The one "Error:" line of a failed command, checked to be alone and without a traceback."""
    assert result.exit_code != 0 and isinstance(result.exception, SystemExit), result.exception
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "Traceback" not in result.output, result.output
    return errors[0]


def test_bad_inputs_are_one_line_errors(fitted, tmp_path):
    _, images, cameras, nerf, _ = fitted
    runner = CliRunner()
    out = str(tmp_path / "n.pt")
    message = one_line_error(runner.invoke(cli, ["fit-nerf", str(tmp_path), str(cameras), "-o", out, *FAST]))
    assert "not in" in message
    shrunk = read_cameras(cameras)
    shrunk.width, shrunk.height = 16, 12
    write_cameras(tmp_path / "small.npz", shrunk)
    message = one_line_error(
        runner.invoke(cli, ["fit-nerf", str(images), str(tmp_path / "small.npz"), "-o", out, *FAST])
    )
    assert "do not match" in message
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "view_000.png").write_bytes(b"not a png")
    message = one_line_error(
        runner.invoke(cli, ["fit-nerf", str(tmp_path / "images"), str(cameras), "-o", out, *FAST])
    )
    assert "view_00" in message
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    message = one_line_error(
        runner.invoke(cli, ["render-nerf", str(tmp_path / "bad.pt"), str(cameras), "-o", str(tmp_path / "r")])
    )
    assert "not a readable nerf.pt" in message
    message = one_line_error(
        runner.invoke(
            cli, ["render-nerf", str(nerf), str(cameras), "-o", str(tmp_path / "r"), "--views", "99"]
        )
    )
    assert "--views" in message
