"""`fignetctl make-dataset`: ground-truth trajectories from PyBullet in the MOVi style."""

import re

import click

from fignetctl.commands import options


def parse_shard(ctx, param, value):
    """'i/n' -> (i, n) with 0 <= i < n; click.BadParameter otherwise."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", value or "")
    if not match or not int(match[1]) < int(match[2]):
        raise click.BadParameter(f"{value!r} is not a shard 'i/n' with 0 <= i < n, e.g. 0/4")
    return int(match[1]), int(match[2])


@click.command("make-dataset")
@click.option(
    "--preset",
    type=click.Choice(["movi-b", "movi-c"]),
    default="movi-b",
    show_default=True,
    help="Shapes and materials, after Kubric's MOVi-B / MOVi-C.",
)
@click.option(
    "-n",
    "--num-trajectories",
    type=click.IntRange(min=1, max=10**7),
    default=16,
    show_default=True,
    help="Trajectories of the whole run (all shards together).",
)
@click.option(
    "--fps",
    type=click.IntRange(1, 240),
    default=None,
    help="Recorded frames per second; must divide 240.  [default: 30]",
)
@click.option(
    "--duration",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Seconds per trajectory.  [default: 4]",
)
@options.seed_option
@click.option(
    "--shard",
    default="0/1",
    show_default=True,
    callback=parse_shard,
    help="Write only shard i of n: the trajectories k with k mod n = i.",
)
@click.option(
    "--split",
    type=click.Choice(["train", "test", "all"]),
    default="train",
    show_default=True,
    help="Which shapes (movi-c holds 10% out for test).",
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1, max=1024),
    default=1,
    show_default=True,
    help="Worker processes, each with its own PyBullet.",
)
@click.option(
    "-o", "--output", type=click.Path(dir_okay=False), required=True, help="Trajectory file (.h5) to write."
)
@options.overwrite_option
def make_dataset(preset, num_trajectories, fps, duration, seed, shard, split, jobs, output, overwrite):
    """Ground-truth trajectories from PyBullet: 3-10 objects tossed onto a floor.

    Settings follow Kubric's MOVi-B / MOVi-C workers (docs/make-dataset.md); frames are
    recorded at --fps into a trajectory file. Scenes whose objects tunnel through the floor,
    interpenetrate or explode are dropped, counted and replaced. Shards of one --seed hold
    exactly the trajectories of the unsharded run. Prints the output path on stdout.

    \b
    Example:
      fignetctl make-dataset --preset movi-b -n 1000 --seed 1 --shard 0/4 --jobs 2 -o b-0.h5
    """
    import json
    import time

    from fignetctl import __version__
    from fignetctl.core import movi, shapes
    from fignetctl.core.trajectory import write_trajectories

    path = options.output_path(output, overwrite)
    config = movi.movi_config(preset, fps=fps, duration=duration)
    assets = shapes.load_shapes(preset, split)
    indices = movi.shard_indices(num_trajectories, *shard)
    start = time.perf_counter()
    simulated = movi.generate(assets, config, seed, indices, jobs)
    results = list(options.progress(simulated, total=len(indices), unit="traj", desc="make-dataset"))
    stats = movi.dataset_stats(results, time.perf_counter() - start, jobs)
    click.echo(summary_line(stats), err=True)
    attrs = {
        "source": "fignetctl make-dataset",
        "fignetctl_version": __version__,
        "preset": preset,
        "seed": seed,
        "shard": f"{shard[0]}/{shard[1]}",
        "num_trajectories": num_trajectories,
        "split": split,
        "config": config.to_json(),
        "stats": json.dumps(stats),
        "trajectories_per_minute": stats["trajectories_per_minute"],
    }
    write_trajectories(path, movi.dataset_file(results, assets, config, num_trajectories, attrs))
    click.echo(str(path))


def summary_line(stats: dict) -> str:
    """One line for stderr: kept, dropped by reason, throughput."""
    dropped = ", ".join(f"{count} {reason}" for reason, count in stats["dropped"].items())
    return (
        f"kept {stats['kept']}/{stats['requested']} trajectories ({stats['given_up']} given up); "
        f"dropped scenes: {dropped}; {stats['trajectories_per_minute']:.1f} trajectories/minute "
        f"with {stats['jobs']} job(s)"
    )
