"""`fignetctl build-graph`: meshes + volume.npz -> a 2-frame scene file."""

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.trajectory import read_trajectories
from fignetctl.core.volume import Volume, write_volume


@pytest.fixture
def extracted(tmp_path):
    origin = np.array([0.1, -0.2, 0.06])
    trimesh.creation.box(extents=[0.1, 0.1, 0.1]).export(tmp_path / "object.obj")
    floor = trimesh.creation.box(extents=[0.6, 0.6, 0.05])
    floor.apply_translation([0.1, -0.2, -0.025])
    floor.export(tmp_path / "environment.obj")
    write_volume(
        tmp_path / "volume.npz",
        Volume(origin - 0.06, origin + 0.06, origin, origin - [0.4, 0.4, 0.2], origin + [0.4, 0.4, 0.1]),
    )
    return tmp_path


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_default_drop(extracted):
    result = run(
        "build-graph",
        extracted / "volume.npz",
        "--drop-height",
        "0.2",
        "--delta-z",
        "0.01",
        "-o",
        extracted / "scene.h5",
    )
    assert result.exit_code == 0, result.output
    data = read_trajectories(extracted / "scene.h5")
    assert data.dt == pytest.approx(1 / 30) and data.gravity.tolist() == [0, 0, -9.81]  # the Earth's
    (trajectory,) = data.trajectories.values()
    assert trajectory.num_frames == 2 and list(trajectory.mesh_names) == ["environment", "object"]
    assert list(trajectory.static) == [True, False]
    assert np.allclose(trajectory.positions[:, 1], [[0.1, -0.2, 0.27], [0.1, -0.2, 0.26]])
    assert np.allclose(trajectory.mass, [0.0, 1.0]) and np.allclose(trajectory.restitution, [0.5, 0.7])
    assert np.allclose(trajectory.positions[:, 0], 0.0)
    assert len(data.meshes["object"].faces) == 12


def test_start_velocity_duplicate_and_properties(extracted):
    result = run(
        "build-graph",
        extracted / "volume.npz",
        "--start",
        "0.3,0,0.5",
        "--velocity",
        "3,0,0",
        "--duplicate",
        "--active-mass",
        "2",
        "--passive-friction",
        "0.9",
        "--dt",
        "0.1",
        "--gravity",
        "1.62",
        "-o",
        extracted / "scene.h5",
    )
    assert result.exit_code == 0, result.output
    data = read_trajectories(extracted / "scene.h5")
    assert data.gravity.tolist() == [0, 0, -1.62]
    (trajectory,) = data.trajectories.values()
    assert list(trajectory.static) == [True, True, False]
    assert np.allclose(trajectory.positions[:, 1], [0.1, -0.2, 0.06])  # the original stays
    assert np.allclose(trajectory.positions[:, 2], [[0.0, 0, 0.5], [0.3, 0, 0.5]])
    assert trajectory.mass[2] == 2 and trajectory.friction[0] == pytest.approx(0.9)
    assert trajectory.friction[1] == pytest.approx(0.9)  # the static original is environment now


@pytest.mark.parametrize("name", ["fignet-star-movi-b", "fignet-movi-b"])
def test_default_properties_are_ones_the_bundled_models_were_trained_on(extracted, name):
    from fignetctl.core.model.apply import load_model
    from fignetctl.core.model.trained_ranges import outside_ranges

    assert (
        run("build-graph", extracted / "volume.npz", "--duplicate", "-o", extracted / "scene.h5").exit_code
        == 0
    )
    (trajectory,) = read_trajectories(extracted / "scene.h5").trajectories.values()
    properties = trajectory.properties
    ranges = load_model(name).trained_properties
    assert ranges["static"] and ranges["dynamic"]
    assert outside_ranges(ranges, trajectory.mesh_names, trajectory.static, properties) == []
    properties[0, 1], properties[2, 0] = 0.5, 1e-3  # the paper's FIGNet* passive friction, active mass
    found = outside_ranges(ranges, trajectory.mesh_names, trajectory.static, properties)
    assert (
        len(found) == 2 and "'environment' has friction 0.5 and restitution 0.5, not a material" in found[0]
    )
    assert "'object' has mass 0.001, outside the" in found[1]
    properties[0, 1], properties[2] = 0.3, [1.0, 0.5, 0.5]  # each value between MOVi's two materials
    (found,) = outside_ranges(ranges, trajectory.mesh_names, trajectory.static, properties)
    assert "(0.4, 0.3), (0.8, 0.7)" in found


def test_errors(extracted):
    (extracted / "bad.npz").write_text("nope")
    result = run("build-graph", extracted / "bad.npz", "-o", extracted / "s.h5")
    assert result.exit_code == 1 and "not a readable volume.npz" in result.output
    (extracted / "object.obj").write_text("# nothing\n")
    result = run("build-graph", extracted / "volume.npz", "-o", extracted / "s.h5")
    assert result.exit_code == 1 and "object.obj" in result.output and "Traceback" not in result.output
    result = run("build-graph", extracted / "volume.npz", "--start", "1,2", "-o", extracted / "s.h5")
    assert result.exit_code == 2 and "3 comma-separated" in result.output
    result = run("build-graph", extracted / "volume.npz", "--gravity", "0", "-o", extracted / "s.h5")
    assert result.exit_code == 2 and "--gravity" in result.output and not (extracted / "s.h5").exists()


def test_drop_report_sees_landing_rest_and_penetration():
    import dataclasses

    from fignetctl.core.scene_building import drop_report
    from tests.conftest import box_drop_file

    data = box_drop_file(frames=3)
    trajectory = data.trajectories["00000"]
    frames = 40
    z = np.concatenate([np.linspace(2.0, 0.5, 20), np.full(20, 0.5)])  # falls, lands (half-size 0.5), rests
    positions = np.zeros((frames, 2, 3), np.float32)
    positions[:, 1, 2] = z
    quaternions = np.tile(np.array([1, 0, 0, 0], np.float32), (frames, 2, 1))
    landed = dataclasses.replace(
        data,
        trajectories={"00000": dataclasses.replace(trajectory, positions=positions, quaternions=quaternions)},
    )
    report = drop_report(landed)
    assert report["min_clearance_m"] == pytest.approx(0.0, abs=1e-5) and report["at_rest"]
    assert report["rest_time_s"] == pytest.approx(19 * data.dt)
    positions = positions.copy()
    positions[20:, 1, 2] = 0.46  # sinks 4 cm into the floor
    sunk = dataclasses.replace(
        data,
        trajectories={"00000": dataclasses.replace(trajectory, positions=positions, quaternions=quaternions)},
    )
    assert drop_report(sunk)["min_clearance_m"] == pytest.approx(-0.04, abs=1e-5)
