"""`fignetctl render-views` through click, on tiny captures."""

import inspect

from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.cameras import read_cameras

TINY = ["--views", "4", "--width", "32", "--height", "24", "--objects", "2"]


def run(*args):
    """Invoke render-views with stdout and stderr kept apart (click 8.1 needs mix_stderr=False)."""
    apart = {"mix_stderr": False} if "mix_stderr" in inspect.signature(CliRunner.__init__).parameters else {}
    return CliRunner(**apart).invoke(cli, ["render-views", *args])


def test_writes_a_capture_and_prints_its_folder(tmp_path):
    out = tmp_path / "capture"
    result = run(*TINY, "--seed", "2", "--video-step", "2", "-o", str(out))
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == str(out)
    assert "rendered 4 views 32x24" in result.stderr and "ms per view" in result.stderr
    cameras = read_cameras(out / "ground_truth" / "cameras.npz")
    assert len(cameras) == 4 and (cameras.width, cameras.height) == (32, 24)
    assert all((out / "images" / name).is_file() for name in cameras.image_names)
    for name in (
        "video.mp4",
        "prompts.json",
        "ground_truth/depth.npz",
        "ground_truth/masks.npz",
        "ground_truth/scene.json",
        "ground_truth/objects/table.obj",
        "ground_truth/objects/tray.obj",
    ):
        assert (out / name).is_file(), name


def test_two_views_are_enough(tmp_path):
    result = run("--views", "2", "--width", "48", "--height", "36", "--no-video", "-o", str(tmp_path / "two"))
    assert result.exit_code == 0, result.output
    prompts = (tmp_path / "two" / "prompts.json").read_text()
    assert '"view_000.png"' in prompts and '"view_001.png"' in prompts


def test_no_video_and_overwrite(tmp_path):
    out = tmp_path / "capture"
    assert run(*TINY, "--no-video", "-o", str(out)).exit_code == 0
    assert not (out / "video.mp4").exists()
    refused = run(*TINY, "-o", str(out))
    assert refused.exit_code == 2 and "exists; pass --overwrite" in refused.stderr
    assert not (out / "video.mp4").exists()
    replaced = run(*TINY, "--overwrite", "-o", str(out))
    assert replaced.exit_code == 0, replaced.output
    assert (out / "video.mp4").is_file()


def test_bad_options_are_one_line_errors_without_traceback(tmp_path):
    for args, hint in (
        (["--views", "0"], "--views"),
        (["--width", "2"], "--width"),
        (["--objects", "7"], "--objects"),
    ):
        result = run(*args, "-o", str(tmp_path / "x"))
        assert result.exit_code == 2 and hint in result.stderr, result.stderr
        assert "Traceback" not in result.stderr + result.stdout
    assert not (tmp_path / "x").exists()


def test_help_has_an_example():
    result = run("--help")
    assert (
        result.exit_code == 0 and "Example:" in result.stdout and "fignetctl render-views -o" in result.stdout
    )
