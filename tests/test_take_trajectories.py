"""scripts/take_trajectories.py: a run of trajectories of a file, read back as they were."""

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.errors import FignetError, FormatError
from tests.conftest import box_drop_file

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "take_trajectories.py"


def _script():
    spec = importlib.util.spec_from_file_location("take_trajectories", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def four_drops(tmp_path):
    """Four box drops from other heights (so each trajectory differs), frames 5 to 8 long."""
    data = box_drop_file(frames=5)
    trajectories = {
        f"{k:05d}": box_drop_file(frames=5 + k, height=1.0 + k).trajectories["00000"] for k in range(4)
    }
    return write_trajectories(tmp_path / "four.h5", dataclasses.replace(data, trajectories=trajectories))


def test_the_taken_trajectories_read_back_as_in_the_source(four_drops, tmp_path):
    taken = _script().take(four_drops, tmp_path / "two.h5", 2, start=1)
    source, part = read_trajectories(four_drops), read_trajectories(taken)
    assert list(part.trajectories) == ["00001", "00002"]
    assert part.dt == source.dt and np.array_equal(part.gravity, source.gravity)
    for key, trajectory in part.trajectories.items():
        original = source.trajectories[key]
        for field in ("positions", "quaternions", "velocities", "angular_velocities", "mass", "static"):
            np.testing.assert_array_equal(getattr(trajectory, field), getattr(original, field))
    for name, mesh in part.meshes.items():
        np.testing.assert_array_equal(mesh.vertices, source.meshes[name].vertices)


def test_asking_for_more_than_the_file_holds_or_a_non_trajectory_file_leaves_no_output(four_drops, tmp_path):
    destination = tmp_path / "out.h5"
    with pytest.raises(FignetError, match="holds 4 trajectories, not 5"):
        _script().take(four_drops, destination, 3, start=2)
    not_hdf5 = tmp_path / "notes.h5"
    not_hdf5.write_text("not a trajectory file")
    with pytest.raises(FormatError, match="not a trajectory file"):
        _script().take(not_hdf5, destination, 1)
    assert not destination.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["four.h5", "notes.h5"]
