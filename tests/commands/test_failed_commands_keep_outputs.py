"""A command whose input is corrupt fails in one line (exit != 0, no traceback) and leaves the
output that already exists untouched (issue 6)."""

import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli

GARBAGE = bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8))
PRECIOUS = b"an earlier good output\n"


def _corrupt(path, content=GARBAGE):
    path.write_bytes(content)
    return path


def _rollout(tmp):
    return [
        "rollout",
        _corrupt(tmp / "scene.h5"),
        "--steps",
        "2",
        "-o",
        tmp / "out.h5",
        "--overwrite",
    ], tmp / "out.h5"


def _build_graph(tmp):
    return [
        "build-graph",
        _corrupt(tmp / "volume.npz"),
        "-o",
        tmp / "scene.h5",
        "--overwrite",
    ], tmp / "scene.h5"


def _extract_mesh(tmp):
    (tmp / "out").mkdir()
    arguments = [
        "extract-mesh",
        _corrupt(tmp / "nerf.pt"),
        "--cameras",
        _corrupt(tmp / "cameras.npz"),
        "--box",
        "0,0,0,1,1,1",
        "-o",
        tmp / "out",
        "--overwrite",
    ]
    return arguments, tmp / "out" / "object.obj"


def _fit_nerf(tmp):
    (tmp / "images").mkdir()
    return [
        "fit-nerf",
        tmp / "images",
        _corrupt(tmp / "cameras.npz"),
        "-o",
        tmp / "nerf.pt",
        "--overwrite",
    ], tmp / "nerf.pt"


def _capture_poses(tmp):
    arguments = [
        "capture-poses",
        "--import-cameras",
        _corrupt(tmp / "in.npz"),
        "-o",
        tmp / "cameras.npz",
        "--overwrite",
    ]
    return arguments, tmp / "cameras.npz"


def _rerender(tmp):
    arguments = [
        "rerender",
        _corrupt(tmp / "nerf.pt"),
        _corrupt(tmp / "volume.npz"),
        _corrupt(tmp / "rollout.h5"),
        "-o",
        tmp / "video.mp4",
        "--overwrite",
    ]
    return arguments, tmp / "video.mp4"


def _train_resume(tmp):
    from fignetctl.core.trajectory import write_trajectories
    from tests.conftest import box_drop_file

    dataset = write_trajectories(tmp / "train.h5", box_drop_file(frames=6))
    return ["train", dataset, "-o", tmp / "model.pt", "--steps", "2", "--resume"], tmp / "model.pt"


@pytest.mark.parametrize(
    "command", [_rollout, _build_graph, _extract_mesh, _fit_nerf, _capture_poses, _rerender, _train_resume]
)
def test_failed_command_keeps_the_existing_output(tmp_path, command):
    arguments, output = command(tmp_path)
    if output.name == "model.pt":
        _corrupt(output, PRECIOUS)  # --resume reads the output itself: a corrupt checkpoint
    else:
        output.write_bytes(PRECIOUS)
    before = sorted(p.name for p in output.parent.iterdir())
    result = CliRunner().invoke(cli, [str(a) for a in arguments])
    assert result.exit_code not in (0, None), result.output
    assert isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output
    errors = [line for line in result.output.splitlines() if line.startswith("Error")]
    assert len(errors) == 1, result.output
    assert output.read_bytes() == PRECIOUS
    assert sorted(p.name for p in output.parent.iterdir()) == before  # no temporary file left
