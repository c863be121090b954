"""No output is replaced without --overwrite: for every output a command writes (the main
file or folder, --json, --rerun, --log-csv, --frames, --video, --export-transforms), an existing
one ends the command in one error line, is left byte for byte as it was, and nothing else is
written."""

import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from tests.fuzz_corpus import BOX, base_files

PRECIOUS = b"an earlier output the user wants to keep\n"

# (command line with {slot} inputs and {out} outputs, an output file made to exist beforehand)
CASES = [
    ("render-views -o {out}/capture --views 2 --width 16 --height 16 --no-video", "capture/view_000.png"),
    ("make-dataset --preset movi-b -n 1 -o {out}/data.h5", "data.h5"),
    ("import-kubric {kubric} --assets {assets} -o {out}/kubric.h5", "kubric.h5"),
    ("capture-poses --import-cameras {cameras} -o {out}/cameras.npz", "cameras.npz"),
    ("capture-poses --import-cameras {cameras} -o {out}/cameras.npz --json {out}/poses.json", "poses.json"),
    ("capture-poses --import-cameras {cameras} -o {out}/cameras.npz --rerun {out}/poses.rrd", "poses.rrd"),
    (
        "capture-poses --import-cameras {cameras} -o {out}/cameras.npz --export-transforms {out}/t.json",
        "t.json",
    ),
    ("fit-nerf {images} {cameras} --steps 1 --device cpu -o {out}/nerf.pt", "nerf.pt"),
    ("fit-nerf {images} {cameras} --steps 1 --device cpu -o {out}/nerf.pt --json {out}/f.json", "f.json"),
    ("fit-nerf {images} {cameras} --steps 1 --device cpu -o {out}/nerf.pt --rerun {out}/f.rrd", "f.rrd"),
    ("render-nerf {nerf} {cameras} -o {out}/views", "views/top.png"),
    (
        "extract-mesh {nerf} --cameras {cameras} --box " + BOX + " --device cpu -o {out}/mesh",
        "mesh/object.obj",
    ),
    (
        "extract-mesh {nerf} --cameras {cameras} --masks {masks} --device cpu -o {out}/mesh",
        "mesh/masks/top.png",
    ),
    (
        "extract-mesh {nerf} --cameras {cameras} --box "
        + BOX
        + " --device cpu -o {out}/mesh --json {out}/m.json",
        "m.json",
    ),
    ("build-graph {volume} -o {out}/scene.h5", "scene.h5"),
    ("build-graph {volume} -o {out}/scene.h5 --json {out}/g.json", "g.json"),
    ("rollout {trajectory} --steps 2 -o {out}/rollout.h5", "rollout.h5"),
    ("rollout {trajectory} --steps 2 -o {out}/rollout.h5 --json {out}/r.json", "r.json"),
    ("rollout {trajectory} --steps 2 -o {out}/rollout.h5 --rerun {out}/r.rrd", "r.rrd"),
    ("train {trajectory} --state positions --steps 1 --size tiny -o {out}/model.pt", "model.pt"),
    (
        "train {trajectory} --state positions --steps 1 --size tiny -o {out}/model.pt --log-csv {out}/loss.csv",
        "loss.csv",
    ),
    (
        "train {trajectory} --state positions --steps 1 --size tiny -o {out}/model.pt --rerun {out}/t.rrd",
        "t.rrd",
    ),
    ("evaluate {trajectory} --max-trajectories 1 -o {out}/metrics.json", "metrics.json"),
    ("show {trajectory} --json {out}/show.json", "show.json"),
    ("show {trajectory} --video {out}/show.mp4", "show.mp4"),
    ("show {trajectory} --rerun {out}/show.rrd", "show.rrd"),
    ("bench-memory {trajectory} --samples 1 --repeats 1 --size tiny --json {out}/bench.json", "bench.json"),
    (
        "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --device cpu -o {out}/v.mp4",
        "v.mp4",
    ),
    (
        "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --device cpu -o {out}/v.mp4 "
        "--frames {out}/frames",
        "frames/frame_00000.png",
    ),
    (
        "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --device cpu -o {out}/v.mp4 "
        "--json {out}/v.json",
        "v.json",
    ),
    (
        "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --device cpu -o {out}/v.mp4 "
        "--rerun {out}/v.rrd",
        "v.rrd",
    ),
]


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    import cv2
    import numpy as np

    files = base_files(tmp_path_factory.mktemp("outputs-base"))
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.pinhole import project
    from tests.core.test_rerender import BOX_LOWER, BOX_UPPER

    files["masks"] = files["images"].parent / "masks"
    files["masks"].mkdir()
    cameras = read_cameras(files["cameras"])
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
    corners = BOX_LOWER + corners * (BOX_UPPER - BOX_LOWER)
    for name, K, c2w in zip(cameras.image_names, cameras.K, cameras.c2w):
        points, _ = project(K, c2w, corners)
        mask = np.zeros((cameras.height, cameras.width), np.uint8)
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(points - 0.5).astype(np.int32)), 255)
        cv2.imwrite(str(files["masks"] / name), mask)
    return files


def _snapshot(folder):
    return {
        str(path.relative_to(folder)): path.read_bytes() if path.is_file() else None
        for path in sorted(folder.rglob("*"))
    }


@pytest.mark.parametrize("command, existing", CASES, ids=[f"{c.split()[0]}:{e}" for c, e in CASES])
def test_an_existing_output_is_refused_and_kept(base, tmp_path, command, existing):
    out = tmp_path / "out"
    out.mkdir()
    (out / existing).parent.mkdir(parents=True, exist_ok=True)
    (out / existing).write_bytes(PRECIOUS)
    before = _snapshot(out)
    arguments = command.format(**{slot: str(path) for slot, path in base.items()}, out=out).split(" ")
    result = CliRunner().invoke(cli, arguments)
    assert result.exit_code != 0 and result.exception is None or isinstance(result.exception, SystemExit)
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error")]
    assert len(errors) == 1 and "--overwrite" in errors[0], result.output[-600:]
    assert _snapshot(out) == before
    assert not any(name.startswith(".") for name in (p.name for p in out.rglob("*")))
