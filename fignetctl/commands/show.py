"""`fignetctl show`: summarise a trajectory file; optionally a rerun recording or an mp4."""

import functools

import click

from fignetctl.commands import options
from fignetctl.stages import show as stage


def _output_option(flag, help):
    return click.option(flag, flag[2:] + "_path", type=click.Path(dir_okay=False), default=None, help=help)


@click.command("show")
@click.argument("path", type=click.Path(dir_okay=False))
@options.settings_options(stage.Settings)
@_output_option("--json", "Also write the summary as json.")
@_output_option("--video", "Render an mp4 preview of the trajectory.")
@_output_option("--png", "Render one frame (--frame) to PNG.")
@options.rerun_option
@options.overwrite_option
def show(path, overwrite, **values):
    """Summarise the trajectory file PATH: objects, meshes, frames, energy over time.

    Prints the summary on stdout. --rerun logs one trajectory (moving meshes, a trace of
    each object's centre, energy plots) to a recording; --video renders an mp4 preview.

    \b
    Example:
      fignetctl show b.h5
      fignetctl show b.h5 --trajectory 00003 --video b.mp4 --rerun b.rrd
      fignetctl show b.h5 --json b.json --png b.png --frame 40
    """
    settings = options.settings_from(stage.Settings, values)
    given = {flag: values[f"{flag}_path"] for flag in ("json", "video", "png", "rerun")}  # in this order
    outputs = {f"{f}_path": options.output_path(p, overwrite, f"--{f}") for f, p in given.items() if p}
    echo = functools.partial(click.echo, nl=False)
    stage.run(path, settings, **outputs, progress=options.progress, echo=echo)
