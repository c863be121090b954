"""Data-parallel training: 2 processes on the CPU under torchrun (gloo)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.trajectory import write_trajectories
from tests.conftest import box_drop_file

TORCHRUN = Path(sys.executable).with_name("torchrun")
FIGNETCTL = Path(sys.executable).with_name("fignetctl")
pytestmark = pytest.mark.skipif(
    not (TORCHRUN.exists() and FIGNETCTL.exists()),
    reason="torchrun or the fignetctl script is not installed beside this python",
)


def _torchrun_train(data, model, steps, *extra):
    command = [
        str(TORCHRUN),
        "--standalone",
        "--nproc_per_node",
        "2",
        str(FIGNETCTL),
        "train",
        str(data),
        "-o",
        str(model),
        "--size",
        "tiny",
        "--steps",
        str(steps),
        "--checkpoint-every",
        "2",
        *extra,
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(command, capture_output=True, text=True, env=env, timeout=300)


def _why(result) -> str:
    """What the ranks said before one died (torchrun's own report is only the tail)."""
    said = [
        line
        for line in result.stderr.splitlines()
        if any(w in line for w in ("rror", "abort", "what()", "terminate"))
    ]
    return "\n".join(said)[-3000:] + "\n...\n" + result.stderr[-1000:]


def test_two_processes_train_and_resume_together(tmp_path):
    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    model = tmp_path / "model.pt"
    first = _torchrun_train(data, model, 4)
    assert first.returncode == 0, _why(first)
    state = torch.load(model, weights_only=True)["training_state"]
    assert state["step"] == 4 and state["world_size"] == 2
    resumed = _torchrun_train(data, model, 6, "--resume")
    assert resumed.returncode == 0, _why(resumed)
    assert torch.load(model, weights_only=True)["training_state"]["step"] == 6
    single = CliRunner().invoke(
        cli, ["train", str(data), "-o", str(model), "--size", "tiny", "--steps", "8", "--resume"]
    )
    assert single.exit_code == 1 and "resume it with as many" in single.output


def test_two_processes_stop_together_at_the_time_limit(tmp_path):
    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    model = tmp_path / "model.pt"
    stopped = _torchrun_train(data, model, 5, "--time-limit", "1e-9")
    assert stopped.returncode == 0 and "stopped at the time limit after step 1 of 5" in stopped.stderr
    state = torch.load(model, weights_only=True)["training_state"]
    assert state["step"] == 1 and state["world_size"] == 2
