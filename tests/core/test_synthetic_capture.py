"""The bundled capture (`fignetctl.core.synthetic_capture`, written by the render-views stage) on tiny
renders: files, geometry, prompts."""

import json

import numpy as np
import pytest

from fignetctl.core import pinhole
from fignetctl.core import synthetic_capture as capture
from fignetctl.core.cameras import read_cameras
from fignetctl.core.media import read_video_info
from fignetctl.errors import FignetError
from fignetctl.stages.render_views import write_capture

TINY = dict(views=8, width=96, height=72, texture_size=256, points=300, video_step=2)


def render_capture(out, overwrite=False, **values):
    """The capture of `values` (CaptureSettings fields) written into the folder `out`."""
    return write_capture(out, capture.capture_settings(**values), overwrite)


@pytest.fixture(scope="module")
def tiny_capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("capture") / "scene"
    summary = render_capture(out, seed=1, **TINY)
    return out, summary


def load(out):
    cameras = read_cameras(out / "ground_truth" / "cameras.npz")
    depth = np.load(out / "ground_truth" / "depth.npz")["depth"]
    with np.load(out / "ground_truth" / "masks.npz") as data:
        masks, ids, names = data["masks"], data["ids"], data["names"]
    scene = json.loads((out / "ground_truth" / "scene.json").read_text())
    prompts = json.loads((out / "prompts.json").read_text())
    return cameras, depth, masks, dict(zip(ids.tolist(), names.tolist())), scene, prompts


def test_every_file_is_present_and_readable(tiny_capture):
    import cv2
    import trimesh

    out, summary = tiny_capture
    cameras, depth, masks, names, scene, prompts = load(out)
    assert [str(n) for n in cameras.image_names] == [f"view_{i:03d}.png" for i in range(8)]
    for name in cameras.image_names:
        image = cv2.imread(str(out / "images" / name))
        assert image.shape == (72, 96, 3) and image.std() > 10
    video = cv2.VideoCapture(str(out / "video.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 16 == summary["video_frames"]
    assert video.read()[1].shape == (72, 96, 3) and read_video_info(out / "video.mp4")["codec"] == "h264"
    assert (cameras.width, cameras.height) == (96, 72) and len(cameras.points) == 300
    assert depth.shape == masks.shape == (8, 72, 96) and depth.dtype == np.float32 and masks.dtype == np.int16
    assert np.isfinite(depth).all() and (masks >= 0).all()  # the backdrop closes the scene
    assert scene["format"] == "fignetctl.scene" and prompts["format"] == "fignetctl.prompts"
    roles = {o["name"]: o["role"] for o in scene["objects"]}
    assert roles["table"] == "support" and roles["tray"] == "container"
    assert sum(role == "object" for role in roles.values()) == 3 == len(summary["objects"])
    assert names == {o["id"]: o["name"] for o in scene["objects"]}
    for item in scene["objects"]:
        mesh = trimesh.load(out / "ground_truth" / item["gt_mesh"], process=False)
        assert np.allclose(mesh.bounds, item["bounds"], atol=1e-4)
    assert not list(out.parent.glob(".*"))  # no temporary folder left behind


def test_depth_is_the_distance_along_the_axis_to_the_table_plane(tiny_capture):
    cameras, depth, masks, names, _, _ = load(tiny_capture[0])
    table = next(i for i, n in names.items() if n == "table")
    for view in range(len(cameras)):
        rows, columns = np.nonzero(masks[view] == table)
        K, c2w = cameras.K[view], cameras.c2w[view]
        rays = np.stack(
            [(columns + 0.5 - K[0, 2]) / K[0, 0], (rows + 0.5 - K[1, 2]) / K[1, 1], np.ones(len(rows))], 1
        )
        world_rays = rays @ c2w[:3, :3].T
        expected = -c2w[2, 3] / world_rays[:, 2]  # z = 0 is the table top; rays have unit camera z
        assert len(rows) > 100
        np.testing.assert_allclose(depth[view][rows, columns], expected, rtol=2e-4, atol=2e-4)


def test_object_meshes_project_onto_their_masks(tiny_capture):
    import trimesh

    out = tiny_capture[0]
    cameras, depth, masks, _, scene, _ = load(out)
    for item in (o for o in scene["objects"] if o["movable"]):
        vertices = trimesh.load(out / "ground_truth" / item["gt_mesh"], process=False).vertices
        seen = 0
        for view in range(len(cameras)):
            rows, columns = np.nonzero(masks[view] == item["id"])
            if len(rows) == 0:
                continue
            seen += 1
            uv, z = pinhole.project(cameras.K[view], cameras.c2w[view], vertices)
            low, high = uv.min(0) - 0.5, uv.max(0) - 0.5  # pixel (u, v) is the point (u+0.5, v+0.5)
            assert (z > 0).all()
            assert low[0] - 1 <= columns.min() and columns.max() <= high[0] + 1
            assert low[1] - 1 <= rows.min() and rows.max() <= high[1] + 1
            points = pinhole.unproject(
                cameras.K[view], cameras.c2w[view], columns, rows, depth[view, rows, columns]
            )
            assert np.all((points >= np.min(vertices, 0) - 0.01) & (points <= np.max(vertices, 0) + 0.01))
        assert seen >= 2, item["name"]


def test_cameras_orbit_and_look_at_the_tray(tiny_capture):
    cameras = read_cameras(tiny_capture[0] / "ground_truth" / "cameras.npz")
    target = capture.ring_target()
    offsets = target - cameras.centres
    np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), capture.CaptureSettings().radius, rtol=1e-6)
    forward = cameras.c2w[:, :3, 2]  # OpenCV: z looks forward, y down
    np.testing.assert_allclose(forward, offsets / np.linalg.norm(offsets, axis=1, keepdims=True), atol=1e-6)
    assert (cameras.c2w[:, 2, 1] < 0).all()  # image down points to world down
    assert np.allclose(cameras.K[:, 0, 0], cameras.K[:, 1, 1])
    assert (cameras.points[:, 2] > -capture.TABLE_THICKNESS - 1e-3).all()
    assert (np.abs(cameras.points[:, :2]) < capture.TABLE_HALF + 1e-3).all()


def test_prompts_lie_inside_their_objects_masks(tiny_capture):
    cameras, _, masks, _, scene, prompts = load(tiny_capture[0])
    movable = {o["name"] for o in scene["objects"] if o["movable"]}
    assert {entry["name"] for entry in prompts["objects"]} == movable
    for entry in prompts["objects"]:
        assert len(entry["points"]) >= 2 and len({p["image"] for p in entry["points"]}) == len(
            entry["points"]
        )
        for point in entry["points"]:
            view = cameras.index_of(point["image"])
            assert masks[view, point["v"], point["u"]] == entry["id"]
            assert (masks[view] == entry["id"]).sum() > 0


def test_the_same_seed_gives_the_same_capture_and_another_seed_another(tmp_path):
    small = dict(views=4, width=32, height=24, texture_size=128, points=50, video=False, prompts_per_object=2)
    a = render_capture(tmp_path / "a", seed=5, **small)
    render_capture(tmp_path / "b", seed=5, **small)
    c = render_capture(tmp_path / "c", seed=6, num_objects=4, **small)
    for name in ("images/view_002.png", "prompts.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert not (tmp_path / "a" / "video.mp4").exists()
    assert (tmp_path / "a" / "images/view_000.png").read_bytes() != (
        tmp_path / "c" / "images/view_000.png"
    ).read_bytes()
    assert len(c["objects"]) == 4 and a["views"] == 4


def test_an_existing_output_is_kept_unless_overwrite_and_a_failure_leaves_it(tmp_path, monkeypatch):
    small = dict(views=3, width=24, height=16, texture_size=64, points=20, video=False, prompts_per_object=2)
    out = tmp_path / "scene"
    out.mkdir()
    (out / "prompts.json").write_text("old")  # an earlier capture's file
    with pytest.raises(FignetError, match="exists; pass `overwrite`"):
        render_capture(out, **small)

    def broken(*args, **kwargs):
        raise FignetError("disk full")

    monkeypatch.setattr(capture, "sample_points", broken)
    with pytest.raises(FignetError, match="disk full"):
        render_capture(out, overwrite=True, **small)
    assert (out / "prompts.json").read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == [
        "scene"
    ]
    monkeypatch.undo()
    (out / "notes.txt").write_text("mine")  # not the capture's: replacing the folder would delete it
    with pytest.raises(FignetError, match="holds notes.txt, which this command does not write"):
        render_capture(out, overwrite=True, **small)
    (out / "notes.txt").unlink()
    render_capture(out, overwrite=True, **small)
    assert (out / "prompts.json").read_text() != "old" and (out / "images").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(views=0), "views must be at least 2"),
        (dict(width=4), "width must be in"),
        (dict(num_objects=9), "num_objects must be in"),
        (dict(colour="red"), "bad capture setting"),
    ],
)
def test_bad_settings_are_one_line_errors(tmp_path, settings, message):
    with pytest.raises(FignetError, match=message) as error:
        render_capture(tmp_path / "x", **settings)
    assert "\n" not in str(error.value)
    assert not (tmp_path / "x").exists()


def test_linearize_depth_inverts_the_perspective_depth_buffer():
    near, far = 0.05, 6.0
    z = np.array([0.05, 0.3, 1.0, 2.5, 6.0])
    buffer = (1 / near - 1 / z) / (1 / near - 1 / far)  # OpenGL's window depth
    np.testing.assert_allclose(capture.linearize_depth(buffer, near, far), z, rtol=1e-5)


def test_the_tray_rests_on_the_table_and_the_objects_in_the_tray(tiny_capture):
    scene = json.loads((tiny_capture[0] / "ground_truth" / "scene.json").read_text())
    bounds = {o["name"]: np.array(o["bounds"]) for o in scene["objects"]}
    assert bounds["table"][1, 2] == pytest.approx(0.0) and bounds["tray"][0, 2] == pytest.approx(
        0.0, abs=1e-6
    )
    floor = capture.TRAY_FLOOR_TOP * capture.TRAY.scale + capture.tray_lift()
    half = capture.TRAY_FLOOR_HALF * capture.TRAY.scale
    for item in (o for o in scene["objects"] if o["movable"]):
        low, high = bounds[item["name"]]
        assert low[2] == pytest.approx(floor + 0.001, abs=1e-5)
        assert (np.abs(low[:2]) < half).all() and (np.abs(high[:2]) < half).all()
    assert np.all(np.array(scene["bounds"][0]) <= bounds["backdrop"][0])


def test_video_frame_k_times_step_is_view_k(tiny_capture):
    import cv2

    out = tiny_capture[0]
    video = cv2.VideoCapture(str(out / "video.mp4"))
    frames = [video.read()[1].astype(float) for _ in range(5)]
    views = [cv2.imread(str(out / "images" / f"view_{k:03d}.png")).astype(float) for k in range(3)]
    for k in range(3):  # video_step 2: frames 0, 2, 4 are views 0, 1, 2; H.264 is lossy
        difference = np.abs(frames[2 * k] - views[k]).mean()
        neighbour = np.abs(frames[2 * k + (1 if k < 2 else -1)] - views[k]).mean()
        assert difference < 15 and difference < 0.5 * neighbour


def test_the_measured_camera_height_is_the_cameras_mean_height_above_the_table(tiny_capture):
    out, _ = tiny_capture
    cameras, *_ = load(out)
    measured = json.loads((out / "measurements.json").read_text())["camera_height_m"]
    assert measured == pytest.approx(cameras.centres[:, 2].mean(), abs=1e-6)
    assert 0.2 < measured < 1.0
