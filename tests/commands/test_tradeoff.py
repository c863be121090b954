import json
from pathlib import Path

import torch
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.trajectory import write_trajectories
from tests.conftest import box_drop_file


def run(args):
    return CliRunner().invoke(cli, ["tradeoff", *args])


def test_quick_decimation_device_and_rotations(tmp_path):
    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=6, height=0.6))
    out = tmp_path / "out"
    result = run(["decimation", "device", "rotations", "--quick", "--data", str(data), "-o", str(out)])
    assert result.exit_code == 0, result.output
    for knob in ("decimation", "device", "rotations"):
        for ext in ("json", "csv", "png"):
            assert (out / f"tradeoff-{knob}.{ext}").is_file()
    decimation = json.loads((out / "tradeoff-decimation.json").read_text())
    assert [p["setting"] for p in decimation["points"]] == [64, "full"]
    assert all(p["seconds"]["n"] == 2 and p["error"]["n"] == 1 for p in decimation["points"])
    assert any(p["pareto"] for p in decimation["points"])
    rotations = json.loads((out / "tradeoff-rotations.json").read_text())
    assert [p["setting"] for p in rotations["points"]] == [1, 2]
    assert all(p["failed_rollouts"] == 0 for p in rotations["points"])
    device = json.loads((out / "tradeoff-device.json").read_text())
    if not torch.cuda.is_available():
        assert device["cuda"] == "no GPU here" and [p["setting"] for p in device["points"]] == ["cpu"]
    again = run(["device", "--quick", "--data", str(data), "-o", str(out)])
    assert again.exit_code != 0 and "--overwrite" in again.output


def test_quick_message_passing_trains_two_sizes(tmp_path):
    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=8, height=0.6))
    result = run(
        ["message-passing", "--quick", "--data", str(data), "--train-data", str(data), "-o", str(tmp_path)]
    )
    assert result.exit_code == 0, result.output
    points = json.loads((tmp_path / "tradeoff-message-passing.json").read_text())["points"]
    assert [(p["latent_size"], p["message_passing_steps"]) for p in points] == [(32, 1), (32, 2)]


def test_marching_cubes_needs_a_capture_and_a_nerf(tmp_path):
    result = run(["marching-cubes", "-o", str(tmp_path)])
    assert result.exit_code == 2 and "--capture" in result.output


def test_nerf_steps_needs_a_learning_curve_and_reads_the_given_one(tmp_path):
    result = run(["nerf-steps", "-o", str(tmp_path)])
    assert result.exit_code == 2 and "--nerf-curve" in result.output and not list(tmp_path.iterdir())
    curve = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "nerf_psnr_vs_time.json"
    result = run(["nerf-steps", "--nerf-curve", str(curve), "-o", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "tradeoff-nerf-steps.json").read_text())["points"]
