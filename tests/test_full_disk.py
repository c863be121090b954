"""A full disk at the moment each command commits its output (os.replace raising ENOSPC, the
fault injected in process): one error line that says to free space, the earlier output byte
for byte as it was, and no temporary file left beside it."""

import errno
import os

import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from tests.fuzz_corpus import BOX, base_files

# (command line with {slot} inputs and {out} the output, whether the output is a folder)
WRITERS = [
    ("rollout {trajectory} --steps 2 -o {out}", False),
    ("build-graph {volume} -o {out}", False),
    ("train {trajectory} --state positions --steps 1 --size tiny -o {out}", False),
    ("capture-poses --import-transforms {transforms} --images {images} -o {out}", False),
    ("fit-nerf {images} {cameras} --steps 1 --device cpu -o {out}", False),
    ("rerender {nerf} {volume} {trajectory} --cameras {cameras} --camera 0 --device cpu -o {out}", False),
    ("evaluate {trajectory} --max-trajectories 1 -o {out}", False),
    ("show {trajectory} --json {out}", False),
    ("import-kubric {kubric} --assets {assets} -o {out}", False),
    ("make-dataset --preset movi-b -n 1 -o {out}", False),
    ("bench-memory {trajectory} --samples 1 --repeats 1 --size tiny --json {out}", False),
    ("extract-mesh {nerf} --cameras {cameras} --box " + BOX + " --max-voxel 1 --device cpu -o {out}", True),
    ("render-nerf {nerf} {cameras} -o {out}", True),
]
SUFFIXES = {
    "rollout": ".h5",
    "build-graph": ".h5",
    "import-kubric": ".h5",
    "make-dataset": ".h5",
    "train": ".pt",
    "fit-nerf": ".pt",
    "capture-poses": ".npz",
    "rerender": ".mp4",
    "evaluate": ".json",
    "show": ".json",
    "bench-memory": ".json",
}


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return base_files(tmp_path_factory.mktemp("full-disk-base"))


@pytest.mark.parametrize("command, folder", WRITERS, ids=[w[0].split()[0] for w in WRITERS])
def test_a_full_disk_keeps_the_earlier_output(base, tmp_path, monkeypatch, command, folder):
    name = command.split()[0]
    out = tmp_path / ("out" if folder else f"out{SUFFIXES[name]}")
    if folder:
        out.mkdir()
        for file in ("object.obj", "environment.obj", "volume.npz", "view_000.png"):
            (out / file).write_bytes(b"earlier " + file.encode())
    else:
        out.write_bytes(b"earlier output")
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}

    def full_disk(source, target):
        raise OSError(errno.ENOSPC, "No space left on device", str(target))

    monkeypatch.setattr(os, "replace", full_disk)
    args = command.format(**{k: str(v) for k, v in base.items()}, out=out).split(" ") + ["--overwrite"]
    result = CliRunner().invoke(cli, args)
    monkeypatch.undo()
    assert result.exit_code == 1, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1 and "no space left on device; free some disk space" in errors[0], result.output
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before  # the earlier output as it was, nothing new (no temporary file) beside it
