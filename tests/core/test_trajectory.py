import dataclasses

import h5py
import numpy as np
import pytest

from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.errors import FormatError
from tests.conftest import INDEPENDENT_FIXTURE


def test_write_then_read_round_trip(tmp_path, box_drop):
    box_drop.attrs["seed"] = 7
    box_drop.trajectories["00000"].extras["final_speed"] = np.array([0.0, 1.5], np.float32)
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    back = read_trajectories(path)
    assert back.dt == pytest.approx(box_drop.dt)
    assert back.attrs["seed"] == 7
    original, read = box_drop.trajectories["00000"], back.trajectories["00000"]
    np.testing.assert_array_equal(read.positions, original.positions)
    np.testing.assert_array_equal(read.quaternions, original.quaternions)
    np.testing.assert_array_equal(read.static, original.static)
    assert list(read.mesh_names) == ["floor", "box"]
    np.testing.assert_array_equal(read.extras["final_speed"], [0.0, 1.5])
    np.testing.assert_array_equal(back.meshes["box"].faces, box_drop.meshes["box"].faces)


def test_reads_selected_trajectories_only(tmp_path, box_drop):
    box_drop.trajectories["00001"] = box_drop.trajectories["00000"]
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    assert list(read_trajectories(path, ["00001"]).trajectories) == ["00001"]
    with pytest.raises(FormatError, match="no trajectory '00009'"):
        read_trajectories(path, ["00009"])


@pytest.mark.skipif(not INDEPENDENT_FIXTURE.exists(), reason="../shared is not beside the checkout")
def test_reads_file_from_independent_pybullet_script():
    data = read_trajectories(INDEPENDENT_FIXTURE)
    assert len(data.trajectories) == 2
    for trajectory in data.trajectories.values():
        assert trajectory.static[0] and not trajectory.static[1:].any()
        assert trajectory.positions.shape[0] == 49


def _corrupt(path, dataset, value):
    with h5py.File(path, "r+") as f:
        del f[dataset]
        if value is not None:
            f[dataset] = value


@pytest.mark.parametrize(
    "dataset, value, message",
    [
        ("trajectories/00000/mass", None, "trajectory '00000': missing field 'mass'"),
        ("trajectories/00000/friction", np.ones(3, np.float32), "field 'friction' must be \\(2,\\)"),
        (
            "meshes/box/faces",
            np.array([[0, 1, 99]], np.int32),
            "mesh 'box': field 'faces' refers to vertex 99",
        ),
    ],
)
def test_refuses_missing_or_malformed_fields(tmp_path, box_drop, dataset, value, message):
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    _corrupt(path, dataset, value)
    with pytest.raises(FormatError, match=message):
        read_trajectories(path)


def test_refuses_nan_naming_frame_and_object(tmp_path, box_drop):
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    with h5py.File(path, "r+") as f:
        positions = f["trajectories/00000/positions"][()]
        positions[2, 1, 0] = np.nan
        f["trajectories/00000/positions"][...] = positions
    with pytest.raises(FormatError, match="'positions' is not finite at frame 2, object 1"):
        read_trajectories(path)


def test_refuses_non_unit_quaternion(tmp_path, box_drop):
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    with h5py.File(path, "r+") as f:
        f["trajectories/00000/quaternions"][1, 1] = [1.0, 0.5, 0.0, 0.0]
    with pytest.raises(FormatError, match="not a unit quaternion at frame 1, object 1"):
        read_trajectories(path)


@pytest.mark.parametrize("version", [0, 3])
def test_refuses_unknown_format_version(tmp_path, box_drop, version):
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = version
    with pytest.raises(FormatError, match=f"format_version {version} is not supported"):
        read_trajectories(path)


def test_refuses_wrong_format_and_garbage(tmp_path, box_drop):
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    with h5py.File(path, "r+") as f:
        f.attrs["format"] = "kubric"
    with pytest.raises(FormatError, match="attribute 'format' is 'kubric'"):
        read_trajectories(path)
    garbage = tmp_path / "garbage.h5"
    garbage.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(FormatError, match="not a readable HDF5"):
        read_trajectories(garbage)
    with pytest.raises(FormatError, match="no such file"):
        read_trajectories(tmp_path / "missing.h5")


def test_failed_write_keeps_previous_output(tmp_path, box_drop):
    path = write_trajectories(tmp_path / "t.h5", box_drop)
    before = path.read_bytes()
    broken = dataclasses.replace(box_drop, dt=float("nan"))
    with pytest.raises(FormatError, match="'dt' must be between"):
        write_trajectories(path, broken)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.h5"]


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("dt", 5e-324, "'dt' must be between 1e-06 and 100 seconds"),
        ("dt", 1e300, "'dt' must be between 1e-06 and 100 seconds"),
        ("trajectories/00000/mass", 1e30, r"field 'mass' must be between 0 and 1e\+09"),
        ("trajectories/00000/scales", 1e30, "field 'scales' must be positive and at most 10000"),
    ],
)
def test_values_beyond_physics_are_refused_by_name(tmp_path, box_drop, field, value, message):
    import h5py

    path = write_trajectories(tmp_path / "t.h5", box_drop)
    with h5py.File(path, "r+") as f:
        if field == "dt":
            f.attrs["dt"] = value
        else:
            f[field][...] = value
    with pytest.raises(FormatError, match=message):
        read_trajectories(path)
