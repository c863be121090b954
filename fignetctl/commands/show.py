"""`fignetctl show`: summarise a trajectory file; optionally a rerun recording or an mp4."""

import click

from fignetctl.commands import options


@click.command("show")
@click.argument("path", type=click.Path(dir_okay=False))
@click.option("--trajectory", "trajectory_id", default=None, help="Trajectory for --video/--rerun.  [default: the first]")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), default=None, help="Also write the summary as json.")
@click.option("--video", "video_path", type=click.Path(dir_okay=False), default=None, help="Render an mp4 preview of the trajectory.")
@click.option("--png", "png_path", type=click.Path(dir_okay=False), default=None, help="Render one frame (--frame) to PNG.")
@click.option("--frame", type=int, default=-1, show_default=True, help="Frame for --png (negative counts from the end).")
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
    """
    import json

    from fignetctl.core import inspect, viz
    from fignetctl.core.atomic import atomic_path
    from fignetctl.core.trajectory import read_trajectories

    outputs = {name: options.output_path(p, overwrite, flag) for name, p, flag in (("json", json_path, "--json"), ("video", video_path, "--video"), ("png", png_path, "--png"), ("rerun", rerun_path, "--rerun")) if p}
    data = read_trajectories(path)
    key = _trajectory_key(data, trajectory_id)
    summary = inspect.summarize(data)
    click.echo(inspect.format_summary(summary))
    if "json" in outputs:
        with atomic_path(outputs["json"]) as tmp:
            tmp.write_text(json.dumps(summary, indent=1))
    if "video" in outputs:
        viz.render_preview_video(data, key, outputs["video"], progress=lambda frames: options.progress(frames, unit="frame", desc="video"))
    if "png" in outputs:
        viz.write_preview_png(data, key, outputs["png"], frame=frame)
    if "rerun" in outputs:
        viz.log_trajectory_to_rerun(data, key, outputs["rerun"])


def _trajectory_key(data, trajectory_id):
    if trajectory_id is None:
        return next(iter(data.trajectories))
    if trajectory_id not in data.trajectories:
        known = ", ".join(list(data.trajectories)[:5])
        raise click.BadParameter(f"no trajectory {trajectory_id!r} (the file has {known}, ...)", param_hint="--trajectory")
    return trajectory_id
