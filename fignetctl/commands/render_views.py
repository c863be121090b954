"""`fignetctl render-views`: the bundled capture, a tabletop scene rendered with PyBullet."""

import click

from fignetctl.commands import options
from fignetctl.stages import render_views as stage


@click.command("render-views")
@click.option(
    "-o", "--output", type=click.Path(file_okay=False), required=True, help="Capture folder to write."
)
@options.settings_options(stage.Settings)
@options.overwrite_option
def render_views(output, overwrite, **settings):
    """Render the bundled capture: a textured tabletop scene with a tray and 2-4 objects,
    seen by an orbit of cameras (PyBullet TinyRenderer, offline).

    Writes images/, video.mp4, prompts.json and ground_truth/ (cameras.npz, depth, masks,
    meshes, scene.json) into the --output folder; see docs/render-views.md. Prints the folder
    on stdout.

    \b
    Example:
      fignetctl render-views -o capture --views 40 --width 320 --height 240 --seed 0
      fignetctl render-views -o tiny --views 8 --width 80 --height 60 --no-video
    """
    path = options.output_path(output, overwrite)
    summary = stage.run(path, options.settings_from(stage.Settings, settings), overwrite, options.progress)
    click.echo(summary["message"], err=True)
    click.echo(str(path))
