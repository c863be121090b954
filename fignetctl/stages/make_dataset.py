"""make-dataset: ground-truth trajectories from PyBullet in the MOVi style, into a trajectory file."""

from __future__ import annotations

import dataclasses
import re

from fignetctl.errors import SettingError
from fignetctl.stages import check, setting, to_stderr


@dataclasses.dataclass(frozen=True)
class Settings:
    preset: str = setting(
        "movi-b", "Shapes and materials, after Kubric's MOVi-B / MOVi-C.", choices=("movi-b", "movi-c")
    )
    num_trajectories: int = setting(
        16, "Trajectories of the whole run (all shards together).", low=1, high=10**7
    )
    fps: int | None = setting(
        None, "Recorded frames per second; must divide 240.  [default: 30]", low=1, high=240
    )
    duration: float | None = setting(None, "Seconds per trajectory.  [default: 4]", low=0, low_open=True)
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    shard: tuple[int, int] = setting((0, 1), "Write only shard i of n: the trajectories k with k mod n = i.")
    split: str = setting(
        "train", "Which shapes (movi-c holds 10% out for test).", choices=("train", "test", "all")
    )
    jobs: int = setting(1, "Worker processes, each with its own PyBullet.", low=1, high=1024)


def parse_shard(text) -> tuple[int, int]:
    """'i/n' -> (i, n) with 0 <= i < n; FignetError otherwise."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text or "")
    if not match or not int(match[1]) < int(match[2]):
        raise SettingError(f"{text!r} is not a shard 'i/n' with 0 <= i < n, e.g. 0/4")
    return int(match[1]), int(match[2])


def run(output, settings: Settings = Settings(), progress=None, report=None) -> dict:
    """Simulate the trajectories of shard `settings.shard` and write them to the trajectory file
    `output` (atomically, with the run's settings and its counts in its attributes, never its
    timings or jobs: the same command writes the same bytes, so the file's hash, which `train`
    records, names the data). `report` (default: stderr) gets the summary line (kept, dropped by
    reason, throughput) before the file is written; returns the stats with that line as `message`."""
    import json
    import time

    from fignetctl import __version__
    from fignetctl.core import movi, shapes
    from fignetctl.core.trajectory import write_trajectories

    check(settings)
    shard = settings.shard
    config = movi.movi_config(settings.preset, fps=settings.fps, duration=settings.duration)
    assets = shapes.load_shapes(settings.preset, settings.split)
    indices = movi.shard_indices(settings.num_trajectories, *shard)
    start = time.perf_counter()
    simulated = movi.generate(assets, config, settings.seed, indices, settings.jobs)
    if progress is not None:
        simulated = progress(simulated, total=len(indices), unit="traj", desc="make-dataset")
    results = list(simulated)
    stats = movi.dataset_stats(results, time.perf_counter() - start, settings.jobs)
    message = summary_line(stats)
    (report or to_stderr)(message)
    attrs = {
        "source": "fignetctl make-dataset",
        "fignetctl_version": __version__,
        "preset": settings.preset,
        "seed": settings.seed,
        "shard": f"{shard[0]}/{shard[1]}",
        "num_trajectories": settings.num_trajectories,
        "split": settings.split,
        "config": config.to_json(),
        "stats": json.dumps({key: stats[key] for key in movi.DATASET_COUNTS}),
    }
    write_trajectories(output, movi.dataset_file(results, assets, config, settings.num_trajectories, attrs))
    return {"output": str(output), **stats, "message": message}


def summary_line(stats: dict) -> str:
    """One line for stderr: kept, dropped by reason, throughput and the jobs' speed-up (the
    trajectories' simulation time summed over the wall time)."""
    dropped = ", ".join(f"{count} {reason}" for reason, count in stats["dropped"].items())
    speed_up = stats["simulation_seconds"] / max(stats["seconds"], 1e-9)
    return (
        f"kept {stats['kept']}/{stats['requested']} trajectories ({stats['given_up']} given up); "
        f"dropped scenes: {dropped}; {stats['trajectories_per_minute']:.1f} trajectories/minute "
        f"with {stats['jobs']} job(s), {speed_up:.1f}x one job's simulation rate"
    )
