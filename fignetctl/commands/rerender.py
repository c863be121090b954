"""`fignetctl rerender`: a rollout re-rendered through the static NeRF by ray bending."""

from pathlib import Path

import click

from fignetctl.commands import options
from fignetctl.stages import write_summary


@click.command("rerender")
@click.argument("nerf_path", metavar="NERF", type=click.Path(dir_okay=False))
@click.argument("volume_path", metavar="VOLUME", type=click.Path(dir_okay=False))
@click.argument("rollout_path", metavar="ROLLOUT", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="The mp4 to write.")
@click.option(
    "--frames",
    "frames_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="PNG folder.  [default: OUTPUT without .mp4, plus _frames]",
)
@click.option(
    "--cameras",
    "cameras_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="cameras.npz for --camera (and the orbit's intrinsics).",
)
@click.option(
    "--camera",
    "camera_index",
    type=click.IntRange(-(10**6), 10**6),
    default=None,
    help="Render from this view of --cameras (negative: from the end).",
)
@click.option(
    "--orbit", is_flag=True, help="Render from a camera circling the volume, one turn per --orbit-frames."
)
@click.option(
    "--radius",
    type=options.FiniteFloatRange(min=1e-6, max=1e6),
    default=None,
    help="Orbit radius, m.  [default: the cameras' median distance, else 4x the volume's diagonal]",
)
@click.option(
    "--elevation",
    type=options.FiniteFloatRange(-89, 89),
    default=30.0,
    show_default=True,
    help="Orbit elevation, degrees.",
)
@click.option(
    "--orbit-frames",
    type=click.IntRange(min=1, max=10**5),
    default=None,
    help="Frames per orbit turn.  [default: every output frame]",
)
@click.option(
    "--fov",
    type=options.FiniteFloatRange(5, 170),
    default=50.0,
    show_default=True,
    help="Vertical field of view of an orbit without --cameras, degrees.",
)
@click.option(
    "--width",
    type=click.IntRange(8, 4096),
    default=None,
    help="Image width (K is scaled).  [default: the camera's, or 320]",
)
@click.option(
    "--height",
    type=click.IntRange(8, 4096),
    default=None,
    help="Image height.  [default: keeps the aspect ratio]",
)
@click.option(
    "--mode",
    type=click.Choice(["move", "duplicate"]),
    default="move",
    show_default=True,
    help="Move the object, or leave the original in place.",
)
@click.option(
    "--object",
    "object_name",
    default=None,
    help="Mesh name of the object in the rollout.  [default: the single dynamic object]",
)
@click.option(
    "--trajectory",
    "trajectory_id",
    default=None,
    help="Trajectory id in the rollout file.  [default: the first]",
)
@click.option(
    "--every",
    type=click.IntRange(min=1, max=10**5),
    default=1,
    show_default=True,
    help="Render every K-th rollout step.",
)
@click.option(
    "--fps",
    type=options.FiniteFloatRange(min=0.01, max=1000),
    default=None,
    help="Video frame rate.  [default: real time, 1 / (dt * every)]",
)
@click.option("--trace", is_flag=True, help="Draw the object's path (its projected centre over time).")
@options.rerun_option
@options.device_option
@options.json_option
@options.overwrite_option
def rerender(
    nerf_path,
    volume_path,
    rollout_path,
    output,
    frames_dir,
    cameras_path,
    camera_index,
    orbit,
    radius,
    elevation,
    orbit_frames,
    fov,
    width,
    height,
    mode,
    object_name,
    trajectory_id,
    every,
    fps,
    trace,
    rerun_path,
    device,
    json_path,
    overwrite,
):
    """Re-render the rollout ROLLOUT of the object in VOLUME through the NeRF NERF: each step's
    rigid transform bends the rays that pass through the object's box V_o or its moved box
    (--mode move empties the old place, duplicate keeps it); other pixels come from one
    unedited render. Writes PNG frames and an mp4; prints the mp4's path. See docs/rerender.md.

    \b
    Example:
      fignetctl rerender nerf.pt volume.npz rollout.h5 --cameras cameras.npz --camera 3 -o drop.mp4 --trace
      fignetctl rerender nerf.pt volume.npz rollout.h5 --orbit --radius 1.2 --mode duplicate -o orbit.mp4
    """
    from fignetctl.core import rerender as core
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.provenance import stamp
    from fignetctl.core.trajectory import read_trajectories
    from fignetctl.core.volume import read_volume

    if orbit == (camera_index is not None):
        raise click.UsageError(
            "choose the camera with exactly one of --camera INDEX (with --cameras) or --orbit"
        )
    if camera_index is not None and cameras_path is None:
        raise click.UsageError("--camera needs --cameras cameras.npz")
    video = options.output_path(output, overwrite)
    json_path = options.json_path_checked(json_path, overwrite)
    frames = options.output_path(frames_dir or _default_frames_dir(video), overwrite, "--frames")
    rrd = options.output_path(rerun_path, overwrite, "--rerun") if rerun_path else None
    volume = read_volume(volume_path)
    motion = core.object_motion(read_trajectories(rollout_path), volume, trajectory_id, object_name)
    steps = list(range(0, len(motion), every))
    cameras = _cameras(
        cameras_path,
        camera_index,
        orbit,
        radius,
        elevation,
        orbit_frames,
        fov,
        width,
        height,
        volume,
        len(steps),
    )
    model = load_nerf(nerf_path, device=options.resolve_device(device))
    renderer = core.Rerenderer(model, volume, motion, mode)
    bar = lambda items: options.progress(items, unit="frame", desc="rerender")  # noqa: E731
    summary = core.write_rerender(
        renderer, cameras, steps, frames, video, fps or 1.0 / (motion.dt * every), trace, rrd, bar
    )
    click.echo(
        f"rendered {summary['frames']} frames {summary['width']}x{summary['height']} of {motion.name!r} ({mode}): "
        f"unedited render {summary['background_ms']:.0f} ms, {summary['frame_ms']:.0f} ms per frame "
        f"({100 * summary['bent_fraction']:.1f} % of pixels bent); frames in {frames}",
        err=True,
    )
    provenance = stamp(nerf=nerf_path, volume=volume_path, rollout=rollout_path, cameras=cameras_path)
    write_summary(json_path, {"output": str(video), "frames_dir": str(frames), **summary}, provenance)
    click.echo(str(video))


def _default_frames_dir(video: Path) -> Path:
    return video.with_name(video.stem + "_frames")


def _cameras(cameras_path, index, orbit, radius, elevation, orbit_frames, fov, width, height, volume, count):
    """One camera (K, c2w, width, height) per output frame."""
    import numpy as np

    from fignetctl.core import pinhole
    from fignetctl.core.cameras import read_cameras

    cameras = read_cameras(cameras_path) if cameras_path else None
    if cameras is not None and index is not None and not -len(cameras) <= index < len(cameras):
        raise click.BadParameter(
            f"camera {index} is out of range ({cameras_path} has {len(cameras)} views)", param_hint="--camera"
        )
    native = (cameras.width, cameras.height) if cameras is not None else (320, 240)
    width = width or (native[0] if height is None else max(1, round(native[0] * height / native[1])))
    height = height or max(1, round(native[1] * width / native[0]))
    centre = 0.5 * (volume.lower + volume.upper)
    if cameras is None:
        K = pinhole.intrinsics_from_fov(width, height, fov)
    else:
        K = pinhole.scale_intrinsics(cameras.K[index or 0], width / cameras.width, height / cameras.height)
    if not orbit:
        return [pinhole.Camera(K, cameras.c2w[index], width, height)] * count
    if radius is None:
        radius = (
            float(np.median(np.linalg.norm(cameras.centres - centre, axis=1)))
            if cameras is not None
            else 4.0 * float(np.linalg.norm(volume.upper - volume.lower))
        )
    turn = pinhole.orbit(centre, radius, elevation, orbit_frames or count)
    return [pinhole.Camera(K, turn[i % len(turn)], width, height) for i in range(count)]
