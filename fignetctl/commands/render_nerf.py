"""`fignetctl render-nerf`: colour and z-depth PNGs of cameras from a nerf.pt."""

import click

from fignetctl.commands import options
from fignetctl.stages import render_nerf as stage


@click.command("render-nerf")
@click.argument("nerf", type=click.Path(dir_okay=False))
@click.argument("cameras", type=click.Path(dir_okay=False))
@options.path_option(
    "-o",
    "--output",
    folder=True,
    required=True,
    help="Folder for <name>.png, <name>_depth.png and <name>_depth.npy.",
)
@options.settings_options(stage.Settings)
@options.overwrite_option
def render_nerf(nerf, cameras, output, overwrite, **settings):
    """Render colour and depth of views of CAMERAS (cameras.npz) from a fitted NERF.

    Depth is z-depth along each camera's optical axis (0 where nothing is hit): a colour-mapped
    PNG for looking at, and float32 .npy for use. Prints the folder.

    \b
    Example:
      fignetctl render-nerf nerf.pt cameras.npz -o renders --views 0,3
    """
    out = options.output_path(output, overwrite)
    stage.run(nerf, cameras, out, options.settings_from(stage.Settings, settings))
    click.echo(str(out))
