"""benchmarks/bench_training.py's version 1 copy, which the trainer of before the velocity state
reads: the same file less its velocities, read back by today's reader as version 1."""

import h5py
import numpy as np

from tests.bench import load_benchmark


def test_version_1_copy_drops_the_velocities_and_keeps_the_frames(tmp_path, box_drop):
    from fignetctl.core.trajectory import read_trajectories, write_trajectories

    original = write_trajectories(tmp_path / "v2.h5", box_drop)
    folder = tmp_path / "copy"
    folder.mkdir()
    copy = load_benchmark("bench_training").version_1_copy(original, folder)
    with h5py.File(copy) as f:
        assert f.attrs["format_version"] == 1
    before, after = read_trajectories(original), read_trajectories(copy)
    assert next(iter(before.trajectories.values())).has_velocities
    ((key, trajectory),) = after.trajectories.items()
    assert not trajectory.has_velocities
    np.testing.assert_array_equal(trajectory.positions, before.trajectories[key].positions)
    np.testing.assert_array_equal(trajectory.quaternions, before.trajectories[key].quaternions)
    with h5py.File(original) as f:
        assert f.attrs["format_version"] == 2  # the original is untouched


def test_the_gpu_settings_feed_the_gpu_from_every_core_but_one(monkeypatch):
    import os

    bench = load_benchmark("bench_training")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)), raising=False)
    settings = bench.gpu_settings()
    assert {s.device for s in settings.values()} == {"cuda"}
    assert [s.workers for s in settings.values()] == [0, 4, 15]
    pushforward = bench.pushforward_settings(settings["GPU, 15 graph-building workers"], 128)
    assert [(s.workers, s.pushforward, s.fixed_pushforward) for s in pushforward.values()] == [
        (15, 32, False),
        (15, 32, True),
    ]
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    assert [s.workers for s in bench.gpu_settings().values()] == [0, 1]
