"""`fignetctl show`: summarise a trajectory file; optionally a rerun recording or an mp4."""

import click

from fignetctl.commands import options


@click.command("show")
@click.argument("path", type=click.Path(dir_okay=False))
@click.option(
    "--trajectory",
    "trajectory_id",
    default=None,
    help="Trajectory for --video/--png/--rerun: its id (00003) or number (3).  [default: the first]",
)
@click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write the summary as json.",
)
@click.option(
    "--video",
    "video_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Render an mp4 preview of the trajectory.",
)
@click.option(
    "--png",
    "png_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Render one frame (--frame) to PNG.",
)
@click.option(
    "--frame",
    type=click.IntRange(-(10**9), 10**9),
    default=-1,
    show_default=True,
    help="Frame for --png (negative counts from the end).",
)
@options.rerun_option
@options.overwrite_option
def show(path, trajectory_id, json_path, video_path, png_path, frame, rerun_path, overwrite):
    """Summarise the trajectory file PATH: objects, meshes, frames, energy over time.

    Prints the summary on stdout. --rerun logs one trajectory (moving meshes, a trace of
    each object's centre, energy plots) to a recording; --video renders an mp4 preview.

    \b
    Example:
      fignetctl show b.h5
      fignetctl show b.h5 --trajectory 00003 --video b.mp4 --rerun b.rrd
      fignetctl show b.h5 --json b.json --png b.png --frame 40
    """
    import json

    from fignetctl.core import trajectory_summary, viz
    from fignetctl.core.atomic import atomic_path
    from fignetctl.core.provenance import stamp
    from fignetctl.core.trajectory import read_trajectories

    flags = {"--json": json_path, "--video": video_path, "--png": png_path, "--rerun": rerun_path}
    outputs = {flag: options.output_path(p, overwrite, flag) for flag, p in flags.items() if p}
    data = read_trajectories(path)
    key = _trajectory_key(data, trajectory_id)
    summary = {"file": str(path), **trajectory_summary.summarize(data)}
    click.echo(trajectory_summary.format_summary(summary), nl=False)
    if "--json" in outputs:
        with atomic_path(outputs["--json"]) as tmp:
            tmp.write_text(json.dumps({**summary, **stamp(trajectories=path)}, indent=1) + "\n")
    if "--video" in outputs:
        progress = lambda frames: options.progress(frames, unit="frame", desc="video")  # noqa: E731
        viz.render_preview_video(data, key, outputs["--video"], progress=progress)
    if "--png" in outputs:
        viz.write_preview_png(data, key, outputs["--png"], frame=frame)
    if "--rerun" in outputs:
        viz.log_trajectory_to_rerun(data, key, outputs["--rerun"])


def _trajectory_key(data, trajectory_id):
    """The id asked for, matched exactly or as a number ("3" finds "00003"); the first by default."""
    ids = list(data.trajectories)
    if trajectory_id is None:
        return ids[0]
    if trajectory_id in data.trajectories:
        return trajectory_id
    if trajectory_id.isascii() and trajectory_id.isdecimal():  # "²" is a digit to isdigit(), not to int()
        for key in ids:
            if key.isascii() and key.isdecimal() and int(key) == int(trajectory_id):
                return key
    known = ", ".join(ids[:5]) + (", ..." if len(ids) > 5 else "")
    raise click.BadParameter(
        f"no trajectory {trajectory_id!r} (the file has {known})", param_hint="--trajectory"
    )
