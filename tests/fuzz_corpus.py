"""Every command on a corpus of bad files and bad option values, each outcome classified.

A case is one command line in its own folder: one input file replaced by a damaged copy (empty,
truncated, random bytes, flipped bytes, a zeroed block, another format, a folder, a FIFO,
missing), or one option given a bad value (NaN, ±inf, negative, zero, huge, text, empty). The
command runs in this process (click's runner) under an alarm, and the outcome is one of

    clean       exit ≠ 0 with exactly one "Error: ..." line, nothing written (but the frames a
                rollout kept before it failed, which its error names), no temporary left
    success     exit 0 (the damage missed what the command reads, or the value was usable)
    traceback   an exception escaped the command
    messy       exit ≠ 0, but not one error line
    left_behind a failed command left its output or a temporary file
    hang        still running after the timeout

tests/test_fuzz_commands.py runs a sample and asserts no traceback, messy, left_behind or
hang; benchmarks/fuzz_commands.py runs the whole corpus and reports the counts.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import zlib
from pathlib import Path

import numpy as np
import trimesh

OUTCOMES = ("clean", "success", "traceback", "messy", "left_behind", "hang")
BOX = "-0.3,-0.15,-0.6,0.3,0.15,-0.2"

# (command line, the input slots it reads) with {slot} for an input and {out} for the output;
# every command that reads a file appears with each of its file inputs.
FILE_COMMANDS = [
    ("show {trajectory}", ["trajectory"]),
    ("rollout {trajectory} --steps 2 -o {out}.h5", ["trajectory"]),
    ("rollout {trajectory} --model {model} --steps 2 -o {out}.h5", ["model"]),
    ("evaluate {trajectory} --model {model} --max-trajectories 1 -o {out}.json", ["trajectory", "model"]),
    ("train {trajectory} --state positions --steps 1 --size tiny -o {out}.pt", ["trajectory"]),
    ("build-graph {volume} -o {out}.h5", ["volume"]),
    ("build-graph {volume} --object {object} -o {out}.h5", ["object"]),
    ("render-nerf {nerf} {cameras} -o {out}", ["nerf", "cameras"]),
    (
        "extract-mesh {nerf} --cameras {cameras} --box " + BOX + " --max-voxel 1 --device cpu -o {out}",
        ["nerf"],
    ),
    (
        "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --device cpu -o {out}.mp4",
        ["trajectory", "volume"],
    ),
    ("capture-poses --import-transforms {transforms} --images {images} -o {out}.npz", ["transforms"]),
    ("fit-nerf {images} {cameras} --steps 1 --device cpu -o {out}.pt", ["cameras"]),
    ("bench-memory {trajectory} --samples 1 --repeats 1 --size tiny", ["trajectory"]),
    ("import-kubric {kubric} --assets {assets} -o {out}.h5", ["kubric"]),
]

# (command line with {value}, what the value is)
OPTION_COMMANDS = [
    "render-views -o {out} --width {value}",
    "render-views -o {out} --views {value}",
    "make-dataset --preset movi-b -n {value} -o {out}.h5",
    "make-dataset --preset movi-b -n 1 --seed {value} -o {out}.h5",
    "rollout {trajectory} --steps {value} -o {out}.h5",
    "rollout {trajectory} --steps 2 --sim-scale {value} -o {out}.h5",
    "train {trajectory} --state positions --steps {value} --size tiny -o {out}.pt",
    "train {trajectory} --state positions --steps 1 --batch-size {value} --size tiny -o {out}.pt",
    "train {trajectory} --state positions --steps 1 --learning-rate {value} --size tiny -o {out}.pt",
    "build-graph {volume} --drop-height {value} -o {out}.h5",
    "build-graph {volume} --active-mass {value} -o {out}.h5",
    "fit-nerf {images} {cameras} --steps {value} --device cpu -o {out}.pt",
    "fit-nerf {images} {cameras} --steps 1 --rays-per-batch {value} --device cpu -o {out}.pt",
    "extract-mesh {nerf} --cameras {cameras} --box " + BOX + " --threshold {value} --device cpu -o {out}",
    "extract-mesh {nerf} --cameras {cameras} --box " + BOX + " --resolution {value} --device cpu -o {out}",
    "extract-mesh {nerf} --cameras {cameras} --box {value} --device cpu -o {out}",
    "extract-mesh {nerf} --cameras {cameras} --prompt {value}:10,10 --prompt 1:5,5 --device cpu -o {out}",
    "extract-mesh {nerf} --cameras {cameras} --box {value},-0.15,-0.6,0.3,0.15,-0.2 --device cpu -o {out}",
    "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --fps {value} --device cpu -o {out}.mp4",
    "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera {value} --device cpu -o {out}.mp4",
    "evaluate {trajectory} --max-trajectories {value}",
    "build-graph {volume} --start {value},0,0 -o {out}.h5",
    "build-graph {volume} --velocity 0,0,{value} -o {out}.h5",
    "build-graph {volume} --active-restitution {value} -o {out}.h5",
    "fit-nerf {images} {cameras} --steps 1 --max-image-side {value} --device cpu -o {out}.pt",
    "rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --every {value} --device cpu -o {out}.mp4",
    "rerender {nerf} {volume} {trajectory} --orbit --radius {value} --device cpu -o {out}.mp4",
    "show {trajectory} --trajectory {value}",
    "render-nerf {nerf} {cameras} --views {value} -o {out}",
]
BAD_VALUES = ["nan", "inf", "-inf", "-1", "0", "1e308", "abc", "", "1e-320", "18446744073709551616", "²"]


@dataclasses.dataclass
class Case:
    name: str
    command: str  # with {slot} and {out} placeholders
    slot: str | None = None  # the input replaced by a damaged copy
    damage: str | None = None
    value: str | None = None


def base_files(folder: Path) -> dict:
    """Valid inputs of every kind in `folder`: slot -> path."""
    import cv2

    from fignetctl.core.cameras import Cameras, export_transforms_json, write_cameras
    from fignetctl.core.model.checkpoint import bundled_model_path, export_checkpoint
    from fignetctl.core.nerf import save_nerf
    from fignetctl.core.obj import write_obj
    from fignetctl.core.pinhole import look_at
    from fignetctl.core.trajectory import write_trajectories
    from tests.commands.test_rerender import box_rollout
    from tests.core.test_rerender import BOX_LOWER, BOX_UPPER, REST, solid_field, top_camera, write_volume

    folder.mkdir(parents=True, exist_ok=True)
    save_nerf(folder / "nerf.pt", solid_field(resolution=17))
    write_volume(folder / "volume.npz", lower=BOX_LOWER - 0.05, upper=BOX_UPPER + 0.05, origin=REST)
    box = trimesh.creation.box(BOX_UPPER - BOX_LOWER)  # about its centre, as extract-mesh writes it
    write_obj(folder / "object.obj", box.vertices, box.faces)
    write_obj(
        folder / "environment.obj",
        [[-1, -1, -0.8], [1, -1, -0.8], [1, 1, -0.8], [-1, 1, -0.8]],
        [[0, 1, 2], [0, 2, 3]],
    )
    # at the bundled models' time step, which rollout and evaluate hold a scene's frames to
    write_trajectories(folder / "trajectory.h5", box_rollout(shift=(0.05, 0.03, 0.02), frames=12, dt=1 / 30))
    export_checkpoint(bundled_model_path(), folder / "model.pt")  # as a user ships one: with its checksum
    K, c2w, width, height = top_camera(size=32, focal=40.0)
    cameras = Cameras(
        np.array(["top.png", "side.png"]),
        np.stack([K, K]),
        np.stack([c2w, look_at([2.5, 0.5, 1.5], [0, 0, -0.4])]),
        width,
        height,
    )
    write_cameras(folder / "cameras.npz", cameras)
    images = folder / "images"
    images.mkdir(exist_ok=True)
    for name in cameras.image_names:
        cv2.imwrite(str(images / name), np.full((height, width, 3), 90, np.uint8))
    export_transforms_json(folder / "transforms.json", cameras, image_prefix="images/")
    write_kubric_scene(folder)
    return {
        **{
            name: folder / f"{name}{suffix}"
            for name, suffix in (
                ("nerf", ".pt"),
                ("volume", ".npz"),
                ("object", ".obj"),
                ("trajectory", ".h5"),
                ("model", ".pt"),
                ("cameras", ".npz"),
                ("transforms", ".json"),
            )
        },
        "images": images,
        "kubric": folder / "metadata.json",
        "assets": folder / "assets",
    }


def write_kubric_scene(folder: Path) -> None:
    """A two-frame Kubric metadata.json with one cube, and the cube's mesh in assets/."""
    import json

    from fignetctl.core.obj import write_obj

    (folder / "assets").mkdir(exist_ok=True)
    mesh = trimesh.creation.box()
    write_obj(folder / "assets" / "cube.obj", mesh.vertices, mesh.faces)
    cube = {
        "asset_id": "cube",
        "positions": [[0, 0, 1.0], [0, 0, 0.9]],
        "quaternions": [[1, 0, 0, 0]] * 2,
        "velocities": [[0, 0, -1.0]] * 2,
        "angular_velocities": [[0, 0, 0]] * 2,
        "mass": 1.0,
        "friction": 0.5,
        "restitution": 0.5,
        "size": 0.3,
    }
    document = {
        "metadata": {"frame_rate": 24, "num_frames": 2, "gravity": [0, 0, -9.81]},
        "instances": [cube],
    }
    (folder / "metadata.json").write_text(json.dumps(document))


def damages(flips: int) -> list[str]:
    """The damage labels: fixed kinds, then `flips` single-byte flips and zeroed blocks."""
    fixed = [
        "empty",
        "one_byte",
        "truncated_10",
        "truncated_50",
        "truncated_90",
        "random_bytes",
        "other_format",
        "folder",
        "fifo",
        "missing",
    ]
    return (
        fixed + [f"flip_{i}" for i in range(flips)] + [f"zero_block_{i}" for i in range(max(1, flips // 4))]
    )


NPZ_DAMAGES = ("npy_header", "npy_truncated")
"""For .npz inputs: the zip intact, its first array's .npy header unparsable, or cut short."""


def _npz_member_damaged(source: Path, target: Path, damage: str) -> None:
    import zipfile

    with zipfile.ZipFile(source) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    first = next(iter(members))
    data = members[first]
    if damage == "npy_header":
        length = int.from_bytes(data[8:10], "little")
        header = data[10 : 10 + length].replace(b"}", b" ").replace(b"(", b"((")
        members[first] = data[:10] + header + data[10 + length :]
    else:
        members[first] = data[:20]
    with zipfile.ZipFile(target, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def write_damaged(source: Path, target: Path, damage: str, other: Path) -> None:
    """Make `target` a damaged copy of `source` (or no file at all, for 'missing')."""
    if damage in NPZ_DAMAGES:
        _npz_member_damaged(source, target, damage)
        return
    data = source.read_bytes()
    rng = np.random.default_rng(zlib.crc32(f"{source.name}:{damage}".encode()))
    if damage == "missing":
        return
    if damage == "folder":
        target.mkdir()
        return
    if damage == "fifo":
        os.mkfifo(target)
        return
    if damage == "other_format":
        shutil.copyfile(other, target)
        return
    if damage == "empty":
        data = b""
    elif damage == "one_byte":
        data = data[:1]
    elif damage.startswith("truncated_"):
        data = data[: len(data) * int(damage.split("_")[1]) // 100]
    elif damage == "random_bytes":
        data = rng.integers(0, 256, len(data), dtype=np.uint8).tobytes()
    elif damage.startswith("flip_"):
        buffer = bytearray(data)
        position = int(rng.integers(0, len(buffer)))
        buffer[position] ^= int(rng.integers(1, 256))
        data = bytes(buffer)
    elif damage.startswith("zero_block_"):
        buffer = bytearray(data)
        start = int(rng.integers(0, max(1, len(buffer) - 4096)))
        buffer[start : start + 4096] = bytes(len(buffer[start : start + 4096]))
        data = bytes(buffer)
    target.write_bytes(data)


def corpus(flips: int = 8, values=BAD_VALUES) -> list[Case]:
    """Every file command × input slot × damage, and every option command × bad value."""
    cases = []
    for command, slots in FILE_COMMANDS:
        for slot in slots:
            extra = NPZ_DAMAGES if slot in ("cameras", "volume") else ()
            for damage in (*damages(flips), *extra):
                name = f"{command.split()[0]}:{slot}:{damage}"
                cases.append(Case(f"{name}:{len(cases)}", command, slot=slot, damage=damage))
    for command in OPTION_COMMANDS:
        for value in values:
            cases.append(Case(f"{command.split()[0]}:{value!r}:{len(cases)}", command, value=value))
    return cases


class _Timeout(Exception):
    pass


def run_case(case: Case, base: dict, folder: Path, timeout_s: int = 120) -> dict:
    """Run one case in `folder` (created); {"case", "outcome", "exit_code", "error"}."""
    from click.testing import CliRunner

    from fignetctl.cli import cli

    folder.mkdir(parents=True)
    paths = {slot: str(path) for slot, path in base.items()}
    if case.slot is not None:
        source = base[case.slot]
        other = base["trajectory"] if case.slot != "trajectory" else base["cameras"]
        target = folder / f"damaged{source.suffix}"
        write_damaged(source, target, case.damage, other)
        paths[case.slot] = str(target)
    out = folder / "out"
    line = case.command.format(**paths, out=out, value=case.value if case.value is not None else "")
    args = line.split(" ")  # an empty value stays one empty argument
    before = set(folder.iterdir())

    def alarm(signum, frame):
        raise _Timeout

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(timeout_s)
    try:
        result = CliRunner().invoke(cli, args, catch_exceptions=True)
    except _Timeout:
        return {"case": case.name, "outcome": "hang", "exit_code": None, "error": ""}
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    if isinstance(result.exception, _Timeout):
        return {"case": case.name, "outcome": "hang", "exit_code": None, "error": ""}
    errors = [text for text in result.stderr.splitlines() if text.startswith("Error")]
    error = errors[-1] if errors else ""
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        outcome, error = "traceback", f"{type(result.exception).__name__}: {result.exception}"
    elif result.exit_code == 0:
        outcome = "success"
    elif len(errors) != 1 or "Traceback" in result.output or len(error) < 10:
        outcome = "messy"
    elif [p for p in set(folder.iterdir()) - before if p.name.startswith(("out", "."))] and not (
        "were kept (written to" in error  # rollout keeps the frames before a failure, and says so
    ):
        outcome = "left_behind"
    else:
        outcome = "clean"
    return {"case": case.name, "outcome": outcome, "exit_code": result.exit_code, "error": error[:300]}
