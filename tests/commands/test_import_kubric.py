"""import-kubric on a scene written here in Kubric's metadata.json schema (kubric/utils.py:
get_scene_metadata, get_instance_info); show and evaluate read the result, and evaluate refuses
a model that steps another time than its frames."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.checkpoint import save_checkpoint
from fignetctl.core.obj import write_obj
from fignetctl.core.trajectory import read_trajectories

TWO_FRAME_MODEL = Path(__file__).parents[2] / "benchmarks/results/two-frame-models/fignet-star-movi-b.pt"

FRAMES, FRAME_RATE = 24, 12


def instance(asset_id, positions, spin, **extra):
    """One entry of Kubric's `instances`: the fields get_instance_info writes, and a few more."""
    angles = spin * np.arange(FRAMES) / FRAME_RATE
    quaternions = np.stack([np.cos(angles / 2), np.zeros(FRAMES), np.zeros(FRAMES), np.sin(angles / 2)], 1)
    return {
        "asset_id": asset_id,
        "positions": positions.tolist(),
        "quaternions": quaternions.tolist(),
        "velocities": np.gradient(positions, 1 / FRAME_RATE, axis=0).tolist(),
        "angular_velocities": np.tile([0.0, 0.0, spin], (FRAMES, 1)).tolist(),
        "mass": 2.5,
        "friction": 0.5,
        "restitution": 0.7,
        "image_positions": np.zeros((FRAMES, 2)).tolist(),  # fields the importer does not need
        "bboxes_3d": np.zeros((FRAMES, 8, 3)).tolist(),
        "material": "metal",
        **extra,
    }


@pytest.fixture
def scene(tmp_path):
    times = np.arange(FRAMES) / FRAME_RATE
    falling = np.stack([0.1 * times, np.zeros(FRAMES), np.maximum(2.0 - 5.0 * times**2, 0.5)], 1)
    resting = np.tile([1.0, 1.0, 0.6], (FRAMES, 1))
    document = {
        "flags": {"frame_rate": FRAME_RATE, "step_rate": 240},
        "metadata": {
            "frame_rate": FRAME_RATE,
            "step_rate": 240,
            "num_frames": FRAMES,
            "gravity": [0, 0, -10.0],
        },
        "camera": {"focal_length": 35.0},
        "instances": [
            instance("cube", falling, 3.0, size=0.5, shape="cube"),  # MOVi-B: "size" is the scale
            instance("sphere", resting, 0.0, scale=[1.2, 1.2, 1.2], is_dynamic=False),
        ],
        "events": {"collisions": []},
    }
    metadata = tmp_path / "scene0" / "metadata.json"
    metadata.parent.mkdir()
    metadata.write_text(json.dumps(document))
    assets = tmp_path / "assets"
    cube = trimesh.creation.box()
    (assets / "cube").mkdir(parents=True)
    write_obj(assets / "cube" / "collision_geometry.obj", cube.vertices, cube.faces)
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    write_obj(assets / "sphere.obj", sphere.vertices, sphere.faces)
    return metadata, assets, document


def test_a_kubric_scene_becomes_a_trajectory_that_show_and_evaluate_read(scene, tmp_path):
    metadata, assets, document = scene
    out = tmp_path / "kubric.h5"
    result = CliRunner().invoke(
        cli, ["import-kubric", str(metadata), "--assets", str(assets), "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    data = read_trajectories(out)
    assert data.dt == pytest.approx(1 / FRAME_RATE) and data.gravity.tolist() == [0, 0, -10.0]
    trajectory = data.trajectories["00000"]
    assert list(trajectory.mesh_names) == ["kubric_floor", "cube", "sphere"]
    assert trajectory.static.tolist() == [True, False, True]
    np.testing.assert_allclose(trajectory.scales, [1.0, 0.5, 1.2])
    np.testing.assert_allclose(trajectory.mass, [0.0, 2.5, 0.0])  # static objects have no mass
    np.testing.assert_allclose(trajectory.friction, [0.3, 0.5, 0.5])
    for index, info in enumerate(document["instances"], start=1):
        for field in ("positions", "quaternions", "velocities", "angular_velocities"):
            np.testing.assert_allclose(
                getattr(trajectory, field)[:, index], info[field], rtol=1e-6, atol=1e-6
            )
    np.testing.assert_allclose(data.meshes["cube"].vertices, trimesh.creation.box().vertices, atol=1e-7)
    assert CliRunner().invoke(cli, ["show", str(out)]).exit_code == 0
    report = tmp_path / "metrics.json"
    evaluated = CliRunner().invoke(cli, ["evaluate", str(out), "--max-trajectories", "1", "-o", str(report)])
    assert evaluated.exit_code != 0 and not report.exists()  # the bundled model steps 1/30 s, MOVi 1/12 s
    assert "its frames are 0.0833333 s apart, the model steps 0.0333333 s" in evaluated.output
    # a positions-state model that records no time step takes the file's (a velocity-state one
    # cannot: its inputs are velocities in m/s)
    any_step = tmp_path / "any-step.pt"
    two_frames = load_model(TWO_FRAME_MODEL)
    two_frames.config = dataclasses.replace(two_frames.config, dt=None, gravity=None)
    save_checkpoint(any_step, two_frames)
    evaluated = CliRunner().invoke(
        cli, ["evaluate", str(out), "--model", str(any_step), "--max-trajectories", "1", "-o", str(report)]
    )
    assert evaluated.exit_code == 0, evaluated.output
    assert "constant_velocity" in json.loads(report.read_text())["metrics"]


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d["instances"][0].update(asset_id="teapot"), "no mesh for Kubric asset 'teapot'"),
        (lambda d: d["instances"][0].update(size=[1, 2, 1]), "not uniform"),
        (lambda d: d["instances"][1].update(positions=[[0, 0, 0]] * 3), "'positions' has shape"),
        (lambda d: d["instances"][0]["quaternions"][3].__setitem__(0, float("nan")), "NaN or inf"),
        (lambda d: d.pop("metadata"), "no 'metadata.frame_rate'"),
        (lambda d: d.update(instances=[]), "has no instances"),
    ],
)
def test_a_scene_it_cannot_convert_is_one_error_line(scene, tmp_path, change, message):
    metadata, assets, document = scene
    change(document)
    metadata.write_text(json.dumps(document))
    out = tmp_path / "kubric.h5"
    result = CliRunner().invoke(
        cli, ["import-kubric", str(metadata), "--assets", str(assets), "-o", str(out)]
    )
    assert result.exit_code == 1 and message in result.output and not out.exists()
    assert len([line for line in result.output.splitlines() if line.startswith("Error")]) == 1
