"""`fignetctl make-dataset` on stand-in shapes (a cube and a ball), short runs."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.trajectory import read_trajectories

FAST = ["--duration", "0.5", "--seed", "3"]


@pytest.fixture(autouse=True)
def stand_in_shapes(monkeypatch):
    """load_shapes returns a cube and a ball (side 2), whatever the preset and split."""
    import trimesh

    from fignetctl.core import shapes

    def asset(name, mesh):
        vertices = np.asarray(mesh.vertices - mesh.center_mass, np.float32)
        return shapes.ShapeAsset(name, vertices, np.asarray(mesh.faces, np.int32), (vertices,), "test")

    stand_ins = [
        asset("cube", trimesh.creation.box((2, 2, 2))),
        asset("ball", trimesh.creation.icosphere(2, 1.0)),
    ]
    calls = []
    monkeypatch.setattr(
        shapes, "load_shapes", lambda preset, split="train": calls.append((preset, split)) or stand_ins
    )
    return calls


def run(*args):
    """Invoke make-dataset with stdout and stderr kept apart (click 8.1 needs mix_stderr=False)."""
    import inspect

    apart = {"mix_stderr": False} if "mix_stderr" in inspect.signature(CliRunner.__init__).parameters else {}
    return CliRunner(**apart).invoke(cli, ["make-dataset", *args])


def test_writes_a_readable_dataset_and_prints_its_path(tmp_path, stand_in_shapes):
    out = tmp_path / "b.h5"
    result = run("-n", "2", "--fps", "60", "--split", "test", *FAST, "-o", str(out))
    assert result.exit_code == 0, result.output
    assert result.stdout.strip() == str(out)
    assert "kept 2/2 trajectories" in result.stderr and "trajectories/minute" in result.stderr
    assert stand_in_shapes == [("movi-b", "test")]
    data = read_trajectories(out)
    assert list(data.trajectories) == ["00000", "00001"]
    assert data.dt == pytest.approx(1 / 60) and data.trajectories["00000"].num_frames == 31
    assert data.attrs["source"] == "fignetctl make-dataset" and data.attrs["shard"] == "0/1"
    assert (data.attrs["preset"], data.attrs["seed"], data.attrs["split"]) == ("movi-b", 3, "test")
    stats = json.loads(data.attrs["stats"])
    assert stats["kept"] == 2 and set(stats["dropped"]) == {"placement", "explosion", "tunnel", "penetration"}
    assert "seconds" not in stats and "trajectories_per_minute" not in data.attrs
    assert json.loads(data.attrs["config"])["fps"] == 60
    assert set(data.meshes) <= {"floor", "cube", "ball"} and "floor" in data.meshes


def test_shards_together_equal_the_unsharded_run(tmp_path):
    whole = tmp_path / "whole.h5"
    assert run("-n", "4", *FAST, "-o", str(whole)).exit_code == 0
    parts = [tmp_path / f"part{i}.h5" for i in range(2)]
    for i, part in enumerate(parts):
        result = run("-n", "4", *FAST, "--shard", f"{i}/2", "--jobs", str(i + 1), "-o", str(part))
        assert result.exit_code == 0, result.output
    expected = read_trajectories(whole).trajectories
    shards = [read_trajectories(part).trajectories for part in parts]
    assert list(shards[0]) == ["00000", "00002"] and list(shards[1]) == ["00001", "00003"]
    merged = {**shards[0], **shards[1]}
    assert sorted(merged) == sorted(expected)
    for key, trajectory in expected.items():
        np.testing.assert_array_equal(merged[key].positions, trajectory.positions)
        np.testing.assert_array_equal(merged[key].quaternions, trajectory.quaternions)
        np.testing.assert_array_equal(merged[key].scales, trajectory.scales)


def test_the_same_seed_gives_an_identical_file(tmp_path):
    """Byte for byte, on any number of jobs: `train` records the file's hash as the data's name,
    and a resume or an export checks it."""
    from fignetctl.core.provenance import file_sha256

    paths = [tmp_path / "a.h5", tmp_path / "b.h5", tmp_path / "c.h5"]
    for path, seed, jobs in zip(paths, ["3", "3", "4"], ["1", "2", "1"]):
        result = run("-n", "2", "--duration", "0.5", "--seed", seed, "--jobs", jobs, "-o", str(path))
        assert result.exit_code == 0, result.output
    assert file_sha256(paths[0]) == file_sha256(paths[1]) != file_sha256(paths[2])
    a, c = (read_trajectories(path).trajectories for path in paths[::2])
    assert not np.array_equal(a["00000"].positions[0], c["00000"].positions[0])


@pytest.mark.parametrize("shard", ["2/2", "1", "a/b", "-1/2", "1/0"])
def test_a_bad_shard_is_a_usage_error(tmp_path, shard):
    result = run("-n", "2", "--shard", shard, "-o", str(tmp_path / "x.h5"))
    assert result.exit_code == 2
    assert "--shard" in result.stderr and "0 <= i < n" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "x.h5").exists()


def test_an_fps_that_does_not_divide_240_is_a_one_line_error(tmp_path):
    result = run("-n", "1", "--fps", "25", "-o", str(tmp_path / "x.h5"))
    assert result.exit_code == 1
    assert "fps 25 does not divide" in result.stderr and "Traceback" not in result.stderr


def test_an_existing_output_is_kept_without_overwrite(tmp_path):
    out = tmp_path / "b.h5"
    out.write_bytes(b"precious")
    result = run("-n", "1", *FAST, "-o", str(out))
    assert result.exit_code == 2 and "--overwrite" in result.stderr
    assert out.read_bytes() == b"precious"
    assert run("-n", "1", *FAST, "-o", str(out), "--overwrite").exit_code == 0
    assert list(read_trajectories(out).trajectories) == ["00000"]
