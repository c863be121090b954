"""Benchmark of `make-dataset`: trajectories per minute with 1 and 2 worker processes.

Both runs make the same trajectories (same seed), side by side, so the ratio is meaningful on
a shared machine even when the absolute numbers move. Writes json (--out).

    .venv/bin/python benchmarks/bench_dataset.py -n 16 --out benchmarks/results/dataset.json
"""

import argparse
import os
import time
from pathlib import Path

from fignetctl.core import movi, shapes
from fignetctl.core.atomic import write_json

DEFAULT_OUT = Path(__file__).parent / "results" / "dataset.json"


def throughput(assets, config, count, jobs):
    started = time.perf_counter()
    results = list(movi.generate(assets, config, seed=1, indices=range(count), jobs=jobs))
    seconds = time.perf_counter() - started
    stats = movi.dataset_stats(results, seconds, jobs)
    return {
        "jobs": jobs,
        "seconds": seconds,
        "trajectories_per_minute": stats["trajectories_per_minute"],
        "dropped": stats["dropped"],
    }


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("-n", type=int, default=16)
    parser.add_argument("--preset", default="movi-b")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args()
    assets = shapes.load_shapes(args.preset, "train")
    config = movi.movi_config(args.preset)
    rows = [throughput(assets, config, args.n, jobs) for jobs in (1, 2)]
    report = {
        "preset": args.preset,
        "trajectories": args.n,
        "fps": config.fps,
        "duration_s": config.duration,
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
        "runs": rows,
        "speedup_2_jobs": rows[0]["seconds"] / rows[1]["seconds"],
    }
    for row in rows:
        print(
            f"make-dataset {args.preset}: {row['trajectories_per_minute']:.0f} trajectories/minute with {row['jobs']} job(s)"
        )
    print(f"2 jobs / 1 job speed-up: {report['speedup_2_jobs']:.2f}x")
    write_json(args.out, report, indent=2)


if __name__ == "__main__":
    main()
