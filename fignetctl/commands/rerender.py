"""`fignetctl rerender`: a rollout re-rendered through the static NeRF by ray bending."""

import click

from fignetctl.commands import options
from fignetctl.stages import rerender as stage

FILE = click.Path(dir_okay=False)


@click.command("rerender")
@click.argument("nerf_path", metavar="NERF", type=FILE)
@click.argument("volume_path", metavar="VOLUME", type=FILE)
@click.argument("rollout_path", metavar="ROLLOUT", type=FILE)
@click.option("-o", "--output", type=FILE, required=True, help="The mp4 to write.")
@click.option(
    "--frames",
    "frames_dir",
    type=click.Path(file_okay=False),
    help="PNG folder.  [default: OUTPUT without .mp4, plus _frames]",
)
@click.option(
    "--cameras", "cameras_path", type=FILE, help="cameras.npz for --camera (and the orbit's intrinsics)."
)
@options.settings_options(stage.Settings)
@options.rerun_option
@options.json_option
@options.overwrite_option
def rerender(output, frames_dir, rerun_path, json_path, overwrite, **values):
    """Re-render the rollout ROLLOUT of the object in VOLUME through the NeRF NERF: each step's
    rigid transform bends the rays that pass through the object's box V_o or its moved box
    (--mode move empties the old place, duplicate keeps it); other pixels come from one
    unedited render. Writes PNG frames and an mp4; prints the mp4's path. See docs/rerender.md.

    \b
    Example:
      fignetctl rerender nerf.pt volume.npz rollout.h5 --cameras cameras.npz --camera 3 -o drop.mp4 --trace
      fignetctl rerender nerf.pt volume.npz rollout.h5 --orbit --radius 1.2 --mode duplicate -o orbit.mp4
    """
    settings = options.settings_from(stage.Settings, values)  # values keeps NERF, VOLUME, ROLLOUT, --cameras
    video = options.output_path(output, overwrite)
    json_path = options.optional_output(json_path, overwrite, "--json")
    frames = options.output_path(frames_dir or stage.default_frames_dir(video), overwrite, "--frames")
    rrd = options.output_path(rerun_path, overwrite, "--rerun") if rerun_path else None
    outputs = {"video": video, "frames": frames, "rerun_path": rrd, "json_path": json_path}
    summary = stage.run(**values, **outputs, settings=settings, progress=options.progress)
    click.echo(summary["message"], err=True)
    click.echo(str(video))
