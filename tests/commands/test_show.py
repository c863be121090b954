import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.media import read_video_info
from fignetctl.core.provenance import file_sha256
from fignetctl.core.trajectory import write_trajectories
from tests.conftest import INDEPENDENT_FIXTURE, box_drop_file


@pytest.fixture
def box_file(tmp_path):
    return write_trajectories(tmp_path / "box.h5", box_drop_file(frames=10, height=1.5))


def test_summary_on_stdout_and_json(box_file, tmp_path):
    result = CliRunner().invoke(cli, ["show", str(box_file), "--json", str(tmp_path / "s.json")])
    assert result.exit_code == 0, result.output
    assert "1 trajectories" in result.output or "1 trajectory" in result.output
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["trajectories"] == 1
    assert summary["per_trajectory"][0]["object_table"][1]["mesh"] == "box"
    assert summary["inputs_sha256"] == {"trajectories": file_sha256(box_file)}


def test_video_has_every_frame_and_shows_motion(box_file, tmp_path):
    video = tmp_path / "b.mp4"
    result = CliRunner().invoke(cli, ["show", str(box_file), "--video", str(video)])
    assert result.exit_code == 0, result.output
    capture = cv2.VideoCapture(str(video))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    assert len(frames) == 10 and frames[0].shape == (360, 480, 3)
    assert read_video_info(video)["codec"] == "h264"
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5


def test_rerun_recording_is_written(box_file, tmp_path):
    rrd = tmp_path / "b.rrd"
    result = CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(rrd)])
    assert result.exit_code == 0, result.output
    assert rrd.stat().st_size > 1000


@pytest.mark.parametrize("content", [None, b"\x89HDF garbage" * 100])
def test_missing_or_corrupt_file_is_one_line_error(tmp_path, content):
    path = tmp_path / "bad.h5"
    if content is not None:
        path.write_bytes(content)
    result = CliRunner().invoke(cli, ["show", str(path)])
    assert result.exit_code == 1
    assert result.output.startswith("Error: ") and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_existing_output_is_kept_without_overwrite(box_file, tmp_path):
    video = tmp_path / "b.mp4"
    video.write_bytes(b"precious")
    result = CliRunner().invoke(cli, ["show", str(box_file), "--video", str(video)])
    assert result.exit_code == 2 and "--overwrite" in result.output
    assert video.read_bytes() == b"precious"


def test_unknown_trajectory_is_named(box_file):
    result = CliRunner().invoke(cli, ["show", str(box_file), "--trajectory", "00042", "--png", "x.png"])
    assert result.exit_code == 2 and "00042" in result.output


@pytest.mark.skipif(not INDEPENDENT_FIXTURE.exists(), reason="../shared is not beside the checkout")
def test_shows_the_independent_fixture(tmp_path):
    result = CliRunner().invoke(
        cli, ["show", str(INDEPENDENT_FIXTURE), "--png", str(tmp_path / "f.png"), "--frame", "30"]
    )
    assert result.exit_code == 0, result.output
    image = cv2.imread(str(tmp_path / "f.png"))
    assert image.shape == (360, 480, 3) and image.std() > 10


def _rerun_executable():
    import shutil
    import sys
    from pathlib import Path

    beside_python = Path(sys.executable).parent / "rerun"
    return str(beside_python) if beside_python.exists() else shutil.which("rerun")


def test_video_container_reports_frame_count_and_size(box_file, tmp_path):
    video = tmp_path / "b.mp4"
    assert CliRunner().invoke(cli, ["show", str(box_file), "--video", str(video)]).exit_code == 0
    capture = cv2.VideoCapture(str(video))
    assert capture.isOpened()
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 10
    assert (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))) == (
        480,
        360,
    )
    assert capture.get(cv2.CAP_PROP_FPS) == pytest.approx(60.0, rel=1e-3)
    assert not list(tmp_path.glob(".b.*"))  # no temporary file left beside it


@pytest.mark.skipif(_rerun_executable() is None, reason="the rerun viewer CLI is not installed")
def test_rerun_recording_passes_rrd_verify(box_file, tmp_path):
    import subprocess

    rrd = tmp_path / "b.rrd"
    assert CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(rrd)]).exit_code == 0
    check = subprocess.run(
        [_rerun_executable(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60
    )
    assert check.returncode == 0, check.stdout + check.stderr


@pytest.mark.skipif(_rerun_executable() is None, reason="the rerun viewer CLI is not installed")
def test_recordings_in_one_folder_share_one_recording_id(box_file, tmp_path, monkeypatch):
    import subprocess

    def recording_id(path):
        printed = subprocess.run(
            [_rerun_executable(), "rrd", "print", str(path)], capture_output=True, text=True, timeout=60
        )
        assert printed.returncode == 0, printed.stderr
        return printed.stdout.split("Recording,", 1)[1].split(")", 1)[0].split(",")[1].strip().strip('"')

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    paths = [tmp_path / "a" / "one.rrd", tmp_path / "a" / "two.rrd", tmp_path / "b" / "one.rrd"]
    for rrd in paths:
        assert CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(rrd)]).exit_code == 0
    ids = [recording_id(p) for p in paths]
    assert ids[0] == ids[1] == str((tmp_path / "a").resolve()) != ids[2]
    monkeypatch.setenv("FIGNETCTL_RECORDING_ID", "batch-7")
    assert (
        CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(paths[2]), "--overwrite"]).exit_code
        == 0
    )
    assert recording_id(paths[2]) == "batch-7"


def test_wrong_format_version_is_one_line_error(box_file):
    import h5py

    with h5py.File(box_file, "r+") as f:
        f.attrs["format_version"] = 99
    result = CliRunner().invoke(cli, ["show", str(box_file)])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1 and "format_version" in result.output


def test_random_bytes_are_one_line_error(tmp_path):
    path = tmp_path / "noise.h5"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    result = CliRunner().invoke(cli, ["show", str(path)])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_overwrite_replaces_every_existing_output(box_file, tmp_path):
    paths = {
        flag: tmp_path / name
        for flag, name in (("--json", "s.json"), ("--png", "f.png"), ("--rerun", "r.rrd"))
    }
    for path in paths.values():
        path.write_bytes(b"old")
    arguments = [item for flag, path in paths.items() for item in (flag, str(path))]
    refused = CliRunner().invoke(cli, ["show", str(box_file), *arguments])
    assert refused.exit_code == 2 and all(p.read_bytes() == b"old" for p in paths.values())
    result = CliRunner().invoke(cli, ["show", str(box_file), *arguments, "--overwrite"])
    assert result.exit_code == 0, result.output
    assert json.loads(paths["--json"].read_text())["frames"] == 10
    assert cv2.imread(str(paths["--png"])).shape == (360, 480, 3)
    assert paths["--rerun"].stat().st_size > 1000


def test_trajectory_by_number_and_frame_out_of_range(box_file, tmp_path):
    ok = CliRunner().invoke(
        cli, ["show", str(box_file), "--trajectory", "0", "--png", str(tmp_path / "a.png")]
    )
    assert ok.exit_code == 0, ok.output
    bad = CliRunner().invoke(cli, ["show", str(box_file), "--png", str(tmp_path / "b.png"), "--frame", "10"])
    assert bad.exit_code == 1 and "frame 10" in bad.output and "Traceback" not in bad.output
    assert not (tmp_path / "b.png").exists()
