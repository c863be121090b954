"""show: a trajectory file summarised; optionally its json, an mp4 or PNG preview, a rerun recording."""

from __future__ import annotations

import dataclasses

from fignetctl.errors import SettingError
from fignetctl.stages import check, setting, write_summary


@dataclasses.dataclass(frozen=True)
class Settings:
    trajectory: str | None = setting(
        None, "Trajectory for --video/--png/--rerun: its id (00003) or number (3).  [default: the first]"
    )
    frame: int = setting(-1, "Frame for --png (negative counts from the end).", low=-(10**9), high=10**9)


def run(
    path,
    settings: Settings = Settings(),
    json_path=None,
    video_path=None,
    png_path=None,
    rerun_path=None,
    progress=None,
    echo=None,
) -> dict:
    """Summarise the trajectory file `path` (objects, meshes, frames, energy over time) and write
    the outputs given: the summary as json, an mp4 preview, one frame as PNG, a rerun recording,
    each of the trajectory `settings.trajectory`. `echo(text)`, when given, gets the printed
    summary as soon as the file is read, before the previews are rendered. Returns the summary."""
    from fignetctl.core import trajectory_summary, viz
    from fignetctl.core.provenance import stamp
    from fignetctl.core.trajectory import read_trajectories

    check(settings)
    data = read_trajectories(path)
    key = trajectory_key(data, settings.trajectory)
    summary = {"file": str(path), **trajectory_summary.summarize(data)}
    if echo is not None:
        echo(trajectory_summary.format_summary(summary))
    write_summary(json_path, summary, stamp(trajectories=path))
    if video_path:
        bar = (lambda frames: progress(frames, unit="frame", desc="video")) if progress else None
        viz.render_preview_video(data, key, video_path, progress=bar)
    if png_path:
        viz.write_preview_png(data, key, png_path, frame=settings.frame)
    if rerun_path:
        viz.log_trajectory_to_rerun(data, key, rerun_path)
    return summary


def trajectory_key(data, trajectory_id):
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
    raise SettingError(f"--trajectory: no trajectory {trajectory_id!r} (the file has {known})")
