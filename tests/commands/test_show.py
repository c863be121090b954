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
from tests.rerun_reading import read_recording, read_recordings, rerun_executable


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


# _release_captures: a test's frame can outlive it in a reference cycle (a CliRunner result's
# traceback reaches back to it), and the garbage collector may then free an open cv2 capture in
# the forked child that reads an HDF5 file (core/hdf5_guard.py), where its decoder threads do
# not exist: the child hangs. So the tests release their captures.


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
    capture.release()  # see _release_captures
    assert len(frames) == 10 and frames[0].shape == (360, 480, 3)
    assert read_video_info(video)["codec"] == "h264"
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5


def test_rerun_recording_is_written(box_file, tmp_path):
    rrd = tmp_path / "b.rrd"
    result = CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(rrd)])
    assert result.exit_code == 0, result.output
    recording = read_recording(rrd)
    objects = ["world/objects/00_floor", "world/objects/01_box"]
    assert recording.entities_under("world/objects") == objects
    for entity in objects:  # the mesh once, its pose at each of the 10 frames
        assert {"Mesh3D:vertex_positions", "Transform3D:translation"} <= recording.components(entity)
        assert recording.times(entity, "frame") == list(range(10)) and recording.rows(entity) == 10
        np.testing.assert_allclose(recording.times(entity, "time"), np.arange(10) * 1e9 / 60, atol=1)  # ns
    assert recording.entities_under("world/traces") == ["world/traces/01_box"]  # the moving one
    plots = recording.entities_under("world/plots")
    assert "world/plots/lowest_vertex_z" in plots and "world/plots/energy/total" in plots
    assert all(recording.rows(plot) == 10 for plot in plots)


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


def test_video_container_reports_frame_count_and_size(box_file, tmp_path):
    video = tmp_path / "b.mp4"
    assert CliRunner().invoke(cli, ["show", str(box_file), "--video", str(video)]).exit_code == 0
    capture = cv2.VideoCapture(str(video))
    assert capture.isOpened()
    count, fps = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), capture.get(cv2.CAP_PROP_FPS)
    size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    capture.release()  # see _release_captures
    assert count == 10 and size == (480, 360)
    assert fps == pytest.approx(60.0, rel=1e-3)
    assert not list(tmp_path.glob(".b.*"))  # no temporary file left beside it


@pytest.mark.skipif(rerun_executable() is None, reason="the rerun viewer CLI is not installed")
def test_rerun_recording_passes_rrd_verify(box_file, tmp_path):
    import subprocess

    rrd = tmp_path / "b.rrd"
    assert CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(rrd)]).exit_code == 0
    check = subprocess.run(
        [rerun_executable(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60
    )
    assert check.returncode == 0, check.stdout + check.stderr


def test_recordings_in_one_folder_share_one_recording_id(box_file, tmp_path, monkeypatch):
    def recording_id(path):
        return read_recording(path).recording_id

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    paths = [tmp_path / "a" / "one.rrd", tmp_path / "a" / "two.rrd", tmp_path / "b" / "one.rrd"]
    for rrd in paths:
        result = CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(rrd)])
        assert result.exit_code == 0, result.output
    ids = [recording_id(p) for p in paths]
    assert ids[0] == ids[1] == str((tmp_path / "a").resolve()) != ids[2]
    monkeypatch.setenv("FIGNETCTL_RECORDING_ID", "batch-7")
    assert (
        CliRunner().invoke(cli, ["show", str(box_file), "--rerun", str(paths[2]), "--overwrite"]).exit_code
        == 0
    )
    assert recording_id(paths[2]) == "batch-7"


def test_a_scenes_stages_record_into_one_recording(tmp_path):
    """Every command that writes a recording, each into the scene's folder: the files open in
    the viewer (`rerun scene/*.rrd`) as ONE recording holding every stage's entities."""
    from fignetctl.core.nerf import save_nerf
    from tests.commands.test_rerender import box_rollout
    from tests.core.synthetic_views import render_views
    from tests.core.test_nerf import write_synthetic_scene
    from tests.core.test_rerender import BOX_LOWER, BOX_UPPER, REST, solid_field, write_volume

    inputs, scene = tmp_path / "inputs", tmp_path / "scene"
    render_views(inputs / "photos", count=8, arc_deg=120)
    images, cameras, _ = write_synthetic_scene(inputs / "nerf")
    box = write_trajectories(inputs / "box.h5", box_drop_file(frames=20, height=5.0))
    save_nerf(inputs / "nerf.pt", solid_field(resolution=33))
    write_volume(inputs / "volume.npz", lower=BOX_LOWER - 0.05, upper=BOX_UPPER + 0.05, origin=REST)
    moved = write_trajectories(inputs / "moved.h5", box_rollout())
    small = ["--max-image-side", "32", "--rays-per-batch", "128", "--steps", "3"]
    commands = {
        "capture-poses": ["--images", inputs / "photos", "--camera-height", 0.5, "-o", scene / "cameras.npz"],
        "fit-nerf": [images, cameras, "-o", scene / "nerf.pt", *small],
        "train": [box, "-o", scene / "model.pt", "--size", "tiny", "--steps", 2],
        "rollout": [box, "--model", scene / "model.pt", "--steps", 3, "-o", scene / "rollout.h5"],
        "show": [scene / "rollout.h5"],
        "rerender": [inputs / "nerf.pt", inputs / "volume.npz", moved, "--orbit", "--every", 2, "--width", 24]
        + ["-o", scene / "video.mp4"],
    }
    for command, arguments in commands.items():
        rrd = scene / f"{command}.rrd"
        result = CliRunner().invoke(cli, [command, *map(str, arguments), "--rerun", str(rrd)])
        assert result.exit_code == 0, (command, result.output)
    paths = sorted(scene.glob("*.rrd"))
    assert [p.stem for p in paths] == sorted(commands)
    together = read_recordings(paths)
    assert together.application_id == "fignetctl" and together.recording_id == str(scene.resolve())
    assert {"world/points", "world/cameras/0000"} <= set(together.entities)  # capture-poses
    assert together.times("fit-nerf/loss", "step") == [1, 2, 3]  # fit-nerf
    assert together.times("train/loss", "step") == [1, 2]  # train
    # rollout and show log the same trajectory (2 + 3 frames) on the same entities
    assert together.times("world/objects/01_box", "frame") == list(range(5))
    assert together.rows("world/objects/01_box") == 2 * 5
    assert together.times("world/camera/image", "frame") == [0, 1]  # rerender


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
