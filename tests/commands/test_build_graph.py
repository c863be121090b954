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
    write_volume(tmp_path / "volume.npz", Volume(origin - 0.06, origin + 0.06, origin, origin - [0.4, 0.4, 0.2], origin + [0.4, 0.4, 0.1]))
    return tmp_path


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_default_drop(extracted):
    result = run("build-graph", extracted / "volume.npz", "--drop-height", "0.2", "--delta-z", "0.01", "-o", extracted / "scene.h5")
    assert result.exit_code == 0, result.output
    data = read_trajectories(extracted / "scene.h5")
    assert data.dt == pytest.approx(1 / 30)
    (trajectory,) = data.trajectories.values()
    assert trajectory.num_frames == 2 and list(trajectory.mesh_names) == ["environment", "object"]
    assert list(trajectory.static) == [True, False]
    assert np.allclose(trajectory.positions[:, 1], [[0.1, -0.2, 0.27], [0.1, -0.2, 0.26]])
    assert np.allclose(trajectory.mass, [0.0, 1e-3]) and np.allclose(trajectory.restitution, [0.3, 0.5])
    assert np.allclose(trajectory.positions[:, 0], 0.0)
    assert len(data.meshes["object"].faces) == 12


def test_start_velocity_duplicate_and_properties(extracted):
    result = run("build-graph", extracted / "volume.npz", "--start", "0.3,0,0.5", "--velocity", "3,0,0", "--duplicate",
                 "--active-mass", "2", "--passive-friction", "0.9", "--dt", "0.1", "-o", extracted / "scene.h5")
    assert result.exit_code == 0, result.output
    (trajectory,) = read_trajectories(extracted / "scene.h5").trajectories.values()
    assert list(trajectory.static) == [True, True, False]
    assert np.allclose(trajectory.positions[:, 1], [0.1, -0.2, 0.06])  # the original stays
    assert np.allclose(trajectory.positions[:, 2], [[0.0, 0, 0.5], [0.3, 0, 0.5]])
    assert trajectory.mass[2] == 2 and trajectory.friction[0] == pytest.approx(0.9)


def test_errors(extracted):
    (extracted / "bad.npz").write_text("nope")
    result = run("build-graph", extracted / "bad.npz", "-o", extracted / "s.h5")
    assert result.exit_code == 1 and "not a readable volume.npz" in result.output
    (extracted / "object.obj").write_text("# nothing\n")
    result = run("build-graph", extracted / "volume.npz", "-o", extracted / "s.h5")
    assert result.exit_code == 1 and "object.obj" in result.output and "Traceback" not in result.output
    result = run("build-graph", extracted / "volume.npz", "--start", "1,2", "-o", extracted / "s.h5")
    assert result.exit_code == 2 and "3 comma-separated" in result.output
