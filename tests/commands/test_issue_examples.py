"""The hostile inputs a review of every command found (one command per cause, as reported):
each now ends in exactly one error line and exit ≠ 0, within seconds, with no traceback and
nothing written."""

import os

import h5py
import numpy as np
import pytest

from tests.conftest import box_drop_file
from tests.core.test_reader_fuzz import _cameras_file, _header_unclosed, _npz_member_replaced, _png_claiming
from tests.fuzz_corpus import BOX, Case, base_files, run_case

SECONDS = 60  # a case still running after this is a hang


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return base_files(tmp_path_factory.mktemp("examples-base"))


def _trajectory(folder, name, change=None, frames=6, **replace):
    """A box-drop trajectory file with root attributes or trajectory datasets changed in place."""
    import dataclasses

    from fignetctl.core.trajectory import write_trajectories

    data = box_drop_file(frames=frames)
    if replace:
        trajectory = dataclasses.replace(data.trajectories["00000"], **replace)
        data = dataclasses.replace(data, trajectories={"00000": trajectory})
    path = write_trajectories(folder / name, data, compression=None)
    if change is not None:
        with h5py.File(path, "a") as f:
            change(f)
    return path


def _set(**values):
    def change(f):
        for key, value in values.items():
            if key in f.attrs:
                f.attrs[key] = value
            else:
                f[f"trajectories/00000/{key}"][...] = value

    return change


def _no_objects(f):
    del f["trajectories/00000"]
    f.create_group("trajectories/00000")


def _transforms(folder, name, matrix):
    import json

    document = {
        "fl_x": 40.0,
        "fl_y": 40.0,
        "cx": 16.0,
        "cy": 16.0,
        "w": 32,
        "h": 32,
        "frames": [
            {"file_path": f"images/{image}", "transform_matrix": matrix} for image in ("top.png", "side.png")
        ],
    }
    path = folder / name
    path.write_text(json.dumps(document).replace("NaN", "NaN"))
    return path


def _fifo(folder, name):
    path = folder / name
    os.mkfifo(path)
    return path


def _images_with_a_bomb(folder, name):
    """The base capture's two image names: one a real 32x32 image, one a PNG declaring 10^10 pixels."""
    import cv2

    images = folder / name
    images.mkdir()
    cv2.imwrite(str(images / "top.png"), np.full((32, 32, 3), 90, np.uint8))
    (images / "side.png").write_bytes(_png_claiming(100_000, 100_000))
    return images


NAN = float("nan")
EYE_NAN = [[NAN] * 4] * 4
ZERO = [[0.0] * 4] * 4

# (id, command line: {slot} = a base input, {out} = an output prefix, {file:<maker>} = a bad file)
CASES = [
    ("render-nerf --scale nan", "render-nerf {nerf} {cameras} --scale nan -o {out}"),
    ("render-nerf --scale inf", "render-nerf {nerf} {cameras} --scale inf -o {out}"),
    ("render-nerf --scale 200", "render-nerf {nerf} {cameras} --scale 200 -o {out}"),
    ("rerender --radius nan", "rerender {nerf} {volume} {trajectory} --orbit --radius nan -o {out}.mp4"),
    ("rerender --radius inf", "rerender {nerf} {volume} {trajectory} --orbit --radius inf -o {out}.mp4"),
    ("rerender --fps inf", "rerender {nerf} {volume} {trajectory} --orbit --fps inf -o {out}.mp4"),
    ("make-dataset --duration inf", "make-dataset --preset movi-b -n 1 --duration inf -o {out}.h5"),
    ("extract-mesh --box nan", "extract-mesh {nerf} --cameras {cameras} --box nan,0,0,1,1,1 -o {out}"),
    (
        "extract-mesh --passive-below inf",
        "extract-mesh {nerf} --cameras {cameras} --box " + BOX + " --passive-below inf -o {out}",
    ),
    ("train --collision-radius nan", "train {trajectory} --collision-radius nan --steps 1 -o {out}.pt"),
    ("train --collision-radius inf", "train {trajectory} --collision-radius inf --steps 1 -o {out}.pt"),
    ("train --learning-rate nan nan", "train {trajectory} --learning-rate nan nan --steps 1 -o {out}.pt"),
    ("train --batch-size 1000", "train {trajectory} --batch-size 100000 --steps 1 -o {out}.pt"),
    ("train --pushforward 4", "train {trajectory} --batch-size 4 --pushforward 4 --steps 1 -o {out}.pt"),
    (
        "train --pushforward-model alone",
        "train {trajectory} --pushforward-model {trajectory} --steps 1 -o {out}.pt",
    ),
    (
        "train --pushforward-model not a model",
        "train {trajectory} --pushforward 1 --pushforward-model {trajectory} --steps 1 -o {out}.pt",
    ),
    ("make-dataset --seed 1e20", "make-dataset --preset movi-b -n 1 --seed 99999999999999999999 -o {out}.h5"),
    (
        "make-dataset --seed 2**70",
        "make-dataset --preset movi-b -n 1 --seed 1180591620717411303424 -o {out}.h5",
    ),
    ("rollout --sim-scale 1e300", "rollout {trajectory} --steps 2 --sim-scale 1e300 -o {out}.h5"),
    ("fit-nerf --rays-per-batch 1e8", "fit-nerf {images} {cameras} --rays-per-batch 100000000 -o {out}.pt"),
    ("show --video dt 5e-324", "show {file:dt_tiny} --video {out}.mp4"),
    ("rerender dt 5e-324", "rerender {nerf} {volume} {file:dt_tiny} --orbit -o {out}.mp4"),
    ("show dt 1e300", "show {file:dt_huge}"),
    ("rollout masses 1e30", "rollout {file:mass_huge} --steps 2 -o {out}.h5"),
    ("rollout scales 1e30", "rollout {file:scale_huge} --steps 2 -o {out}.h5"),
    ("capture-poses NaN transforms", "capture-poses --import-transforms {file:transforms_nan} -o {out}.npz"),
    ("capture-poses zero matrix", "capture-poses --import-transforms {file:transforms_zero} -o {out}.npz"),
    ("train 1 frame", "train {file:one_frame} --steps 1 -o {out}.pt"),
    ("train 2 frames", "train {file:two_frames} --steps 1 -o {out}.pt"),
    ("train all static", "train {file:all_static} --steps 1 -o {out}.pt"),
    ("rollout no objects", "rollout {file:no_objects} --steps 2 -o {out}.h5"),
    ("train no objects", "train {file:no_objects} --steps 1 -o {out}.pt"),
    ("bench-memory no objects", "bench-memory {file:no_objects} --samples 1 --repeats 1 --size tiny"),
    ("show no objects", "show {file:no_objects} --json {out}.json"),
    ("make-dataset under a file", "make-dataset --preset movi-b -n 1 -o {trajectory}/sub/out.h5"),
    ("rollout under a file", "rollout {trajectory} --steps 2 -o {trajectory}/sub/out.h5"),
    ("build-graph under a file", "build-graph {volume} -o {trajectory}/sub/out.h5"),
    ("show /dev/zero", "show /dev/zero"),
    ("train FIFO", "train {file:fifo_h5} --steps 1 -o {out}.pt"),
    ("capture-poses FIFO transforms", "capture-poses --import-transforms {file:fifo_json} -o {out}.npz"),
    (
        "extract-mesh FIFO prompts",
        "extract-mesh {nerf} --cameras {cameras} --prompts {file:fifo_json} --object a -o {out}",
    ),
    ("train missing dataset", "train {out}-missing.h5 --steps 1 -o {out}.pt"),
    ("extract-mesh --prompt ²", "extract-mesh {nerf} --cameras {cameras} --prompt ²:10,10 -o {out}"),
    ("tradeoff empty curve", "tradeoff nerf-steps --nerf-curve {file:empty} -o {out}"),
    ("tradeoff binary curve", "tradeoff nerf-steps --nerf-curve {file:binary} -o {out}"),
    ("rollout -o .", "rollout {trajectory} --steps 2 -o ."),
    ("capture-poses bomb image", "capture-poses --images {file:bomb_images} -o {out}.npz"),
    ("fit-nerf bomb image", "fit-nerf {file:bomb_images} {cameras} --steps 1 -o {out}.pt"),
    ("extract-mesh bomb mask", "extract-mesh {nerf} --cameras {cameras} --masks {file:bomb_masks} -o {out}"),
    ("capture-poses npy header", "capture-poses --import-cameras {file:npy_header} -o {out}.npz"),
]

MAKERS = {
    "dt_tiny": lambda d: _trajectory(d, "dt_tiny.h5", _set(dt=5e-324)),
    "dt_huge": lambda d: _trajectory(d, "dt_huge.h5", _set(dt=1e300)),
    "mass_huge": lambda d: _trajectory(d, "mass.h5", _set(mass=np.array([0.0, 1e30]))),
    "scale_huge": lambda d: _trajectory(d, "scale.h5", _set(scales=np.array([1.0, 1e30]))),
    "transforms_nan": lambda d: _transforms(d, "nan.json", EYE_NAN),
    "transforms_zero": lambda d: _transforms(d, "zero.json", ZERO),
    "one_frame": lambda d: _trajectory(d, "one.h5", frames=1),
    "two_frames": lambda d: _trajectory(d, "two.h5", frames=2),
    "all_static": lambda d: _trajectory(d, "static.h5", static=np.array([True, True])),
    "no_objects": lambda d: _trajectory(d, "none.h5", _no_objects),
    "fifo_h5": lambda d: _fifo(d, "fifo.h5"),
    "fifo_json": lambda d: _fifo(d, "fifo.json"),
    "bomb_images": lambda d: _images_with_a_bomb(d, "bomb_images"),
    "bomb_masks": lambda d: _images_with_a_bomb(d, "bomb_masks"),
    "npy_header": lambda d: _npz_member_replaced(
        _cameras_file(d / "good.npz"), d / "header.npz", "K.npy", _header_unclosed
    ),
    "empty": lambda d: (d / "empty.json").write_bytes(b"") or d / "empty.json",
    "binary": lambda d: (d / "binary.json").write_bytes(bytes(range(256))) or d / "binary.json",
}


@pytest.mark.parametrize("command", [c for _, c in CASES], ids=[i for i, _ in CASES])
def test_each_reported_example_ends_in_one_line(base, tmp_path, command):
    for maker, make in MAKERS.items():
        if "{file:" + maker + "}" in command:
            command = command.replace("{file:" + maker + "}", str(make(tmp_path)))
    folder = tmp_path / "case"  # run_case makes it; the outputs would go there
    result = run_case(Case(command, command), base, folder, timeout_s=SECONDS)
    assert result["outcome"] == "clean", result
    assert not any(folder.iterdir())
