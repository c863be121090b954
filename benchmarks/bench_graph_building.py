"""Graph building: how fast one graph-building worker makes training examples, side by side.

`train --workers N` builds its batches in N processes, and on a GPU machine their speed, not
the GPU's, sets the training throughput ("On a GPU" in docs/simulator.md). This benchmark
times exactly a worker's work, `TrainingBatches[k]` (draw the scenes and frames, add the noise,
build each graph and its targets, collate), for the velocity-state FIGNet* of the GPU runs (no
static receivers, radius 0.2 m), one thread, in a fresh process per checkout and round:

* cold: the scenes are made when first drawn, as in a worker early in a run or on a file of
  more trajectories than it keeps (the meshes are prepared before the clock starts);
* warm: the same batches again, every scene already made.

With --before DIR (a checkout of an earlier commit, e.g. `git worktree add /tmp/before HEAD`
before a change), the checkout's code is timed in the same way, the two taking turns
--rounds times so that a noisy host hurts both alike; figures are medians of process CPU
time per example, and the ratios are before / after.

    python benchmarks/bench_graph_building.py data/movi-b-train.h5 --before /tmp/before \
        -o benchmarks/results/graph-building.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from fignetctl.core.atomic import write_json

ROUND_SCRIPT = r"""
import dataclasses, json, sys, time
import torch
from fignetctl.core.model.scene_data import SceneStore, _cached_mesh
from fignetctl.core.model.training import (
    TRAINING_STATIC_REACH, TrainingBatches, TrainingSettings, simulator_config_for,
)
from fignetctl.core.trajectory import read_trajectories

path, batch_size, batches, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
torch.set_num_threads(1)
data = read_trajectories(path)
config = simulator_config_for("fignet-star", "small", state="velocities", static_receivers=False)
config = dataclasses.replace(config, dt=float(data.dt), gravity=tuple(float(g) for g in data.gravity))
store = SceneStore(data, config, TRAINING_STATIC_REACH)
training = TrainingSettings(batch_size=batch_size, steps=batches + 1, seed=seed)
built = TrainingBatches(store, config, training)
for key in store.keys:  # every mesh prepared before the clock starts, as a worker soon has them
    trajectory = data.trajectories[key]
    for name, static, scale in zip(trajectory.mesh_names, trajectory.static, trajectory.scales):
        _cached_mesh(data, name, bool(static), scale, config, store._meshes)
built[batches]  # imports and first calls, outside the timed batches
store._scenes.clear()
figures = {}
for name in ("cold", "warm"):
    start = time.process_time()
    for k in range(batches):
        built[k]
    figures[name] = (time.process_time() - start) / (batches * batch_size)
print(json.dumps(figures))
"""


def measure(checkout, args) -> dict:
    """{"cold": s, "warm": s} CPU seconds per example of one round in a fresh process that
    imports fignetctl from `checkout`."""
    checkout = str(Path(checkout).resolve())
    command = [sys.executable, "-c", ROUND_SCRIPT, str(Path(args.data).resolve())]
    command += [str(v) for v in (args.batch_size, args.batches, args.seed)]
    env = {**os.environ, "PYTHONPATH": checkout, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(command, capture_output=True, text=True, env=env, cwd=checkout, check=False)
    if result.returncode != 0:
        lines = result.stderr.strip().splitlines()
        sys.exit(f"graph building in {checkout} failed: {lines[-1] if lines else result.returncode}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def commit_of(checkout) -> str:
    """The checkout's commit, "+ changes" where its tracked files differ from it."""

    def git(*arguments):
        result = subprocess.run(
            ["git", "-C", str(checkout), *arguments], capture_output=True, text=True, check=False
        )
        return result.stdout.strip() if result.returncode == 0 else ""

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    return commit + (" + changes" if git("status", "--porcelain", "--untracked-files=no") else "")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n".join(__doc__.splitlines()[1:]),
    )
    parser.add_argument("data", help="a trajectory file with velocities (make-dataset)")
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--batches", type=int, default=8, help="batches timed per round (cold, then warm)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--before", default=None, help="a checkout of an earlier commit to time beside this one"
    )
    parser.add_argument("-o", "--output", default=None, help="write the figures as json here")
    args = parser.parse_args()
    if not Path(args.data).is_file():
        sys.exit(f"{args.data}: no such file; make one with `fignetctl make-dataset --preset movi-b`")
    here = Path(__file__).resolve().parents[1]
    checkouts = {"this checkout": here}
    if args.before:
        if not (Path(args.before) / "fignetctl").is_dir():
            sys.exit(f"{args.before}: not a fignetctl checkout (no fignetctl/ in it)")
        checkouts = {"before": Path(args.before), **checkouts}
    rounds = {name: [] for name in checkouts}
    for round_index in range(args.rounds):
        for name, checkout in checkouts.items():
            rounds[name].append(measure(checkout, args))
            figures = rounds[name][-1]
            print(
                f"round {round_index + 1}/{args.rounds} {name}: cold {1e3 * figures['cold']:.2f} ms, "
                f"warm {1e3 * figures['warm']:.2f} ms per example",
                flush=True,
            )
    results = {
        name: {
            kind: {
                "ms_per_example": 1e3 * statistics.median(r[kind] for r in values),
                "examples_per_second": 1.0 / statistics.median(r[kind] for r in values),
                "rounds_ms": [1e3 * r[kind] for r in values],
            }
            for kind in ("cold", "warm")
        }
        for name, values in rounds.items()
    }
    print("\nmedian CPU time per example, one thread (examples per second):")
    for name, result in results.items():
        print(
            f"  {name}: cold {result['cold']['ms_per_example']:.2f} ms ({result['cold']['examples_per_second']:.1f}/s), "
            f"warm {result['warm']['ms_per_example']:.2f} ms ({result['warm']['examples_per_second']:.1f}/s)"
        )
    report = {
        "data": str(args.data),
        "batch_size": args.batch_size,
        "batches_per_round": args.batches,
        "rounds": args.rounds,
        "model": "fignet-star small, velocity state, no static receivers, radius 0.2 m",
        "commits": {name: commit_of(checkout) for name, checkout in checkouts.items()},
        "results": results,
    }
    if args.before:
        report["before"] = str(Path(args.before).resolve())
        report["speedup"] = {
            kind: results["before"][kind]["ms_per_example"] / results["this checkout"][kind]["ms_per_example"]
            for kind in ("cold", "warm")
        }
        print("  before / this checkout: " + ", ".join(f"{k} {v:.2f}x" for k, v in report["speedup"].items()))
    if args.output:
        write_json(args.output, report)
        print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
