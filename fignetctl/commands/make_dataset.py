"""`fignetctl make-dataset`: ground-truth trajectories from PyBullet in the MOVi style."""

import click

from fignetctl.commands import options
from fignetctl.stages import make_dataset as stage


@click.command("make-dataset")
@options.path_option("-o", "--output", required=True, help="Trajectory file (.h5) to write.")
@options.settings_options(
    stage.Settings,
    num_trajectories={"flags": ("-n",)},
    shard={"default": "0/1", "callback": options.parsed_by(stage.parse_shard)},
)
@options.overwrite_option
def make_dataset(output, overwrite, **settings):
    """Ground-truth trajectories from PyBullet: 3-10 objects tossed onto a floor.

    Settings follow Kubric's MOVi-B / MOVi-C workers (docs/make-dataset.md); frames are
    recorded at --fps into a trajectory file. Scenes whose objects tunnel through the floor,
    interpenetrate or explode are dropped, counted and replaced. Shards of one --seed hold
    exactly the trajectories of the unsharded run. Prints the output path on stdout.

    \b
    Example:
      fignetctl make-dataset --preset movi-b -n 1000 --seed 1 --shard 0/4 --jobs 2 -o b-0.h5
    """
    path = options.output_path(output, overwrite)
    settings = options.settings_from(stage.Settings, settings)
    stage.run(path, settings, options.progress)
    click.echo(str(path))
