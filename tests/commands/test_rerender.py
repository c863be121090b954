import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core import pinhole, rerender
from fignetctl.core.cameras import Cameras, write_cameras
from fignetctl.core.media import read_video_info
from fignetctl.core.nerf import save_nerf
from fignetctl.core.pinhole import look_at
from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile, write_trajectories
from tests.core.test_rerender import BOX_LOWER, BOX_UPPER, REST, solid_field, top_camera, write_volume
from tests.rerun_reading import read_recording

FRAMES = 4


def box_rollout(half=0.5 * (BOX_UPPER - BOX_LOWER), shift=(0.15, 0.1, 0.05), frames=FRAMES, dt=0.1):
    """A static floor and the box, sliding by `shift` per frame from its rest place, `frames`
    frames `dt` s apart."""
    corners = rerender.box_corners(-half, half).astype(np.float32)
    faces = np.array([[0, 1, 2], [1, 3, 2]], np.int32)  # the reader checks indices, not closure
    positions = np.zeros((frames, 2, 3), np.float32)
    positions[:, 1] = REST + np.arange(frames)[:, None] * np.asarray(shift)
    quaternions = np.zeros((frames, 2, 4), np.float32)
    quaternions[..., 0] = 1.0
    trajectory = Trajectory(
        mesh_names=np.array(["floor", "box"], dtype=object),
        scales=np.ones(2, np.float32),
        positions=positions,
        quaternions=quaternions,
        static=np.array([True, False]),
        mass=np.array([0.0, 1.0], np.float32),
        friction=np.full(2, 0.5, np.float32),
        restitution=np.full(2, 0.5, np.float32),
    )
    floor = Mesh(np.array([[-1, -1, -0.8], [1, -1, -0.8], [-1, 1, -0.8], [1, 1, -0.8]], np.float32), faces)
    return TrajectoryFile(
        dt=dt,
        gravity=np.array([0, 0, -10.0]),
        meshes={"floor": floor, "box": Mesh(corners, faces)},
        trajectories={"00000": trajectory},
    )


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rerender")
    save_nerf(folder / "nerf.pt", solid_field(resolution=33))
    write_volume(folder / "volume.npz", lower=BOX_LOWER - 0.05, upper=BOX_UPPER + 0.05, origin=REST)
    write_trajectories(folder / "rollout.h5", box_rollout())
    K, c2w, width, height = top_camera(size=32, focal=40.0)
    side = look_at([2.5, 0.5, 1.5], [0, 0, -0.4])
    write_cameras(
        folder / "cameras.npz",
        Cameras(np.array(["top.png", "side.png"]), np.stack([K, K]), np.stack([c2w, side]), width, height),
    )
    return {
        name: str(folder / f"{name}.{ext}")
        for name, ext in (("nerf", "pt"), ("volume", "npz"), ("rollout", "h5"), ("cameras", "npz"))
    }


def run(inputs, *extra):
    return CliRunner().invoke(
        cli, ["rerender", inputs["nerf"], inputs["volume"], inputs["rollout"], *map(str, extra)]
    )


def read_video(path):
    capture, frames = cv2.VideoCapture(str(path)), []
    while True:
        ok, frame = capture.read()
        if not ok:
            return frames
        frames.append(frame)


def test_fixed_camera_writes_frames_and_video(inputs, tmp_path):
    video = tmp_path / "out.mp4"
    result = run(inputs, "--cameras", inputs["cameras"], "--camera", 0, "-o", video, "--device", "cpu")
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().splitlines()[-1] == str(video)
    pngs = sorted((tmp_path / "out_frames").glob("frame_*.png"))
    assert (
        len(pngs) == FRAMES and len(read_video(video)) == FRAMES and read_video_info(video)["codec"] == "h264"
    )
    first, last = (cv2.imread(str(p))[..., ::-1] for p in (pngs[0], pngs[-1]))
    assert first.shape == (32, 32, 3)
    camera = top_camera(size=32, focal=40.0)
    for image, centre in ((first, REST), (last, REST + 3 * np.array([0.15, 0.1, 0.05]))):
        pixels, _ = camera.project(centre[None])
        u, v = pinhole.pixel_of(pixels)[0]
        assert image[v, u, 0] > 200 and image[v, u, 1] < 60  # the red box where the rollout puts it
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary leftovers


def test_orbit_every_trace_rerun_and_scaled_size(inputs, tmp_path):
    video, frames, rrd = tmp_path / "o.mp4", tmp_path / "pngs", tmp_path / "o.rrd"
    result = run(
        inputs,
        "--orbit",
        "--radius",
        3,
        "--elevation",
        40,
        "--every",
        2,
        "--width",
        24,
        "--trace",
        "--mode",
        "duplicate",
        "--frames",
        frames,
        "--rerun",
        rrd,
        "-o",
        video,
    )
    assert result.exit_code == 0, result.output
    images = [cv2.imread(str(p)) for p in sorted(frames.glob("*.png"))]
    assert len(images) == 2 and images[0].shape == (18, 24, 3)
    assert np.abs(images[0].astype(int) - images[1].astype(int)).mean() > 1  # the camera moved
    recording = read_recording(rrd)  # per frame: the object, the camera's pose and its image
    assert recording.entities_under("world") == [
        "world",
        "world/camera",
        "world/camera/image",
        "world/object",
        "world/trace",
    ]
    for entity in ("world/camera", "world/camera/image", "world/object"):
        assert recording.times(entity, "frame") == [0, 1], entity
    assert recording.rows("world/camera/image") == recording.rows("world/object") == 2
    assert {"Pinhole:image_from_camera", "Transform3D:mat3x3"} <= recording.components("world/camera")
    assert recording.entities["world/trace"].static
    # The H.264 mp4 itself, which rerun's decoder reads: one frame reference per frame.
    assert recording.entities["video"].static and "AssetVideo:blob" in recording.components("video")
    assert recording.times("video", "frame") == [0, 1]


def test_existing_output_needs_overwrite(inputs, tmp_path):
    video = tmp_path / "v.mp4"
    args = ("--cameras", inputs["cameras"], "--camera", 1, "--every", 3, "-o", video)
    assert run(inputs, *args).exit_code == 0
    stale = tmp_path / "v_frames" / "frame_00099.png"  # from an earlier, longer run
    stale.write_bytes(b"")
    result = run(inputs, *args)
    assert result.exit_code != 0 and "--overwrite" in result.output
    notes = tmp_path / "v_frames" / "notes.txt"  # not a frame: --overwrite must not delete it
    notes.write_text("mine")
    refused = run(inputs, *args, "--overwrite")
    assert refused.exit_code == 1 and "holds notes.txt, which this command does not write" in refused.output
    assert notes.exists() and stale.exists()
    notes.unlink()
    assert run(inputs, *args, "--overwrite").exit_code == 0
    assert not stale.exists() and len(list((tmp_path / "v_frames").glob("*.png"))) == 2


def one_line_error(result):
    assert result.exit_code != 0 and "Traceback" not in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1 or "Usage:" in result.output, result.output
    return result.output


@pytest.mark.parametrize("which", ["nerf", "volume", "rollout", "cameras"])
@pytest.mark.parametrize("content", [None, b"garbage" * 50])
def test_missing_or_corrupt_input_is_a_one_line_error(inputs, tmp_path, which, content):
    broken = dict(inputs)
    broken[which] = str(tmp_path / f"bad_{which}")
    if content is not None:
        (tmp_path / f"bad_{which}").write_bytes(content)
    result = run(broken, "--cameras", broken["cameras"], "--camera", 0, "-o", tmp_path / "x.mp4")
    assert one_line_error(result).startswith("Error: ")
    assert not (tmp_path / "x.mp4").exists() and not (tmp_path / "x_frames").exists()


def test_object_that_is_not_the_volumes_is_refused(inputs, tmp_path):
    write_trajectories(tmp_path / "big.h5", box_rollout(half=np.array([0.6, 0.6, 0.6])))
    result = run(dict(inputs, rollout=str(tmp_path / "big.h5")), "--orbit", "-o", tmp_path / "x.mp4")
    assert "does not fit the volume" in one_line_error(result)
    result = run(inputs, "--orbit", "--object", "floor", "-o", tmp_path / "x.mp4")
    assert "static" in one_line_error(result)


@pytest.mark.parametrize(
    "args, message",
    [
        (("--cameras", "CAMS", "--camera", 7), "out of range"),
        (("--orbit", "--cameras", "CAMS", "--camera", 0), "exactly one"),
        ((), "exactly one"),
        (("--camera", 0), "--cameras"),
    ],
)
def test_camera_choice_errors(inputs, tmp_path, args, message):
    args = [inputs["cameras"] if a == "CAMS" else a for a in args]
    result = run(inputs, *args, "-o", tmp_path / "x.mp4")
    assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output
