"""benchmarks/bench_graph_building.py times a worker's batches in a process that imports the
code of the checkout it is given."""

import argparse
from pathlib import Path

from tests.bench import load_benchmark
from tests.conftest import box_drop_file

ROOT = Path(__file__).resolve().parents[2]


def test_a_round_times_cold_and_warm_batches_of_the_given_checkout(tmp_path):
    from fignetctl.core.trajectory import write_trajectories

    data = write_trajectories(tmp_path / "drop.h5", box_drop_file(frames=8))
    bench = load_benchmark("bench_graph_building")
    args = argparse.Namespace(data=str(data), batch_size=2, batches=2, seed=0)
    figures = bench.measure(ROOT, args)
    assert set(figures) == {"cold", "warm"}
    assert all(0.0 < seconds < 10.0 for seconds in figures.values())
    assert bench.commit_of(ROOT)  # the commit the figures belong to
    assert bench.commit_of(tmp_path) == "unknown"
