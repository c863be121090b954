"""`fignetctl import-kubric`: Kubric scenes (metadata.json) as a trajectory file."""

import click

from fignetctl.commands import options
from fignetctl.stages import import_kubric as stage


@click.command("import-kubric")
@click.argument("metadata", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--assets",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder of the assets' collision meshes (the layouts: docs/formats.md).",
)
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Trajectory file (.h5).")
@options.settings_options(stage.Settings)
@options.overwrite_option
def import_kubric(metadata, assets, output, overwrite, **settings):
    """Convert Kubric scenes (each a MOVi-style worker's metadata.json) into one trajectory file:
    one trajectory per scene, the instances with their asset's collision mesh, scale, mass,
    friction, restitution, poses and velocities at every frame, and a static floor at z = 0
    (Kubric keeps its floor out of the instances). See docs/formats.md.

    \b
    Example:
      fignetctl import-kubric movi/*/metadata.json --assets kubasic/ -o movi.h5
      fignetctl show movi.h5
      fignetctl evaluate movi.h5 -o metrics.json
    """
    path = options.output_path(output, overwrite)
    summary = stage.run(metadata, assets, path, options.settings_from(stage.Settings, settings))
    click.echo(summary["message"], err=True)
    click.echo(str(path))
