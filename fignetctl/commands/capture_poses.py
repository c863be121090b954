"""`fignetctl capture-poses`: a folder of images or a video -> cameras.npz (metres, z up)."""

from pathlib import Path

import click

from fignetctl.commands import options
from fignetctl.stages import write_summary


@click.command("capture-poses")
@click.option(
    "--images",
    "images_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Folder of photographs (one size). With --import-*, the images to check the cameras against.",
)
@click.option(
    "--video",
    "video_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="A video; frames are picked with --every and written to --frames-dir.",
)
@click.option(
    "--every",
    type=click.IntRange(min=1, max=10**5),
    default=10,
    show_default=True,
    help="Video: keep the sharpest frame of each run of N frames.",
)
@click.option(
    "--frames-dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Video: where the picked frames go.  [default: images/ beside --output]",
)
@click.option(
    "--matcher",
    type=click.Choice(["auto", "exhaustive", "sequential"]),
    default="auto",
    show_default=True,
    help="Feature matching: all pairs, or neighbours in name order; auto: all pairs up to 120 images.",
)
@click.option(
    "--camera-model",
    type=click.Choice(["SIMPLE_PINHOLE", "PINHOLE"]),
    default="SIMPLE_PINHOLE",
    show_default=True,
    help="One camera shared by all images, without distortion.",
)
@click.option(
    "--import-transforms",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Take the poses from a transforms.json (nerfstudio / instant-ngp) instead of COLMAP.",
)
@click.option(
    "--import-colmap",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Take the poses from a COLMAP sparse model folder (cameras/images/points3D .bin or .txt).",
)
@click.option(
    "--import-cameras",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Re-align or convert an existing cameras.npz.",
)
@click.option(
    "--gravity",
    type=click.Choice(["auto", "plane", "cameras", "none"]),
    default="auto",
    show_default=True,
    help="Up from the support plane in the sparse points, the cameras' mean up, auto (plane, else cameras), or none (keep the input's frame and scale).",
)
@click.option(
    "--support-plane",
    type=click.Choice(["largest", "highest", "lowest"]),
    default="largest",
    show_default=True,
    help="With several horizontal planes in the points (a table on a floor), which one is the support: "
    "the one holding the most points, the highest (a table top) or the lowest (the floor). The planes "
    "found are printed; --camera-height is measured from the one chosen.",
)
@click.option(
    "--camera-height",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Scale: measured mean height (m) of the camera centres above the support plane.  [default: 0.5]",
)
@click.option(
    "--baseline",
    type=(str, str, options.FiniteFloatRange(min=0, min_open=True)),
    default=None,
    metavar="IMAGE_A IMAGE_B METRES",
    help="Scale: measured distance between the cameras of two images (instead of --camera-height).",
)
@click.option(
    "--export-transforms",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also write a transforms.json (OpenGL convention).",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="cameras.npz to write.",
)
@options.seed_option
@options.rerun_option
@options.json_option
@options.overwrite_option
def capture_poses(
    images_dir,
    video_path,
    every,
    frames_dir,
    matcher,
    camera_model,
    import_transforms,
    import_colmap,
    import_cameras,
    gravity,
    support_plane,
    camera_height,
    baseline,
    export_transforms,
    output,
    seed,
    rerun_path,
    json_path,
    overwrite,
):
    """Camera poses of a folder of images or a video, in metres with z up (cameras.npz).

    COLMAP (pycolmap, CPU) finds the poses with one shared pinhole camera; the up direction
    comes from the support plane seen in the sparse points (moved to z = 0), the scale from
    one length you measured: the mean camera height above that plane (--camera-height,
    default 0.5 m) or the distance between two cameras (--baseline). A video's picked frames
    are written to images/ beside the output. Nothing is written when too few images
    register. Prints the output path on stdout. Details: docs/capture-poses.md.

    \b
    Example:
      fignetctl capture-poses --images capture/images --camera-height 0.45 -o capture/cameras.npz
      fignetctl capture-poses --video table.mp4 --every 8 -o table/cameras.npz --rerun table/poses.rrd
      fignetctl capture-poses --import-colmap sparse/0 --images images --gravity plane -o cameras.npz
    """
    from fignetctl.core import sfm, world_alignment
    from fignetctl.core.cameras import export_transforms_json, write_cameras

    sources = {
        "--images": images_dir,
        "--video": video_path,
        "--import-transforms": import_transforms,
        "--import-colmap": import_colmap,
        "--import-cameras": import_cameras,
    }
    given = [flag for flag, value in sources.items() if value is not None and flag != "--images"]
    if len(given) > 1 or (video_path is not None and images_dir is not None) or not (given or images_dir):
        raise click.UsageError(
            "give one input: --images DIR, --video FILE, or one of --import-transforms/--import-colmap/--import-cameras (with --images to check them)"
        )
    if camera_height is not None and baseline is not None:
        raise click.UsageError("--camera-height and --baseline both set the scale; give one")
    output = options.output_path(output, overwrite)
    json_path = options.json_path_checked(json_path, overwrite)
    if export_transforms is not None:
        export_transforms = options.output_path(export_transforms, overwrite, "--export-transforms")
    if rerun_path is not None:
        rerun_path = options.output_path(rerun_path, overwrite, "--rerun")
    settings = sfm.SfmSettings(matcher=matcher, camera_model=camera_model, seed=seed)
    alignment_settings = world_alignment.AlignmentSettings(
        gravity=gravity,
        camera_height=camera_height,
        baseline=baseline,
        seed=seed,
        support_plane=support_plane,
    )

    staged = None
    try:
        if video_path is not None:
            frames_dir = options.output_path(
                frames_dir or output.parent / "images", overwrite, "--frames-dir"
            )
            staged, cameras = _poses_from_video(video_path, frames_dir, every, settings)
            images_dir = frames_dir
        elif given:
            cameras = _imported(import_transforms, import_colmap, import_cameras, images_dir)
        else:
            cameras = sfm.run_sfm(images_dir, settings=settings)
        aligned, alignment = world_alignment.align(cameras, alignment_settings)
        provenance = _provenance(images_dir, video_path, import_transforms, import_colmap, import_cameras)
        write_cameras(output, aligned, provenance)
        if staged is not None:
            staged.commit()
    finally:
        if staged is not None:
            staged.discard()
    click.echo(_summary(aligned, alignment), err=True)
    summary = {
        "output": str(output),
        "cameras": len(aligned),
        "sparse_points": len(aligned.points),
        "up_from": alignment.gravity_source,
        "support_plane_points": alignment.plane_inliers,
        "scale": alignment.scale,
        "scale_from": alignment.scale_source,
        "support_planes": list(alignment.planes),
    }
    write_summary(json_path, summary, provenance)
    if export_transforms is not None:
        prefix = "" if images_dir is None else _relative_prefix(images_dir, export_transforms.parent)
        export_transforms_json(export_transforms, aligned, image_prefix=prefix)
    if rerun_path is not None:
        sfm.log_cameras_to_rerun(rerun_path, aligned, images_dir)
    click.echo(str(output))


def _poses_from_video(video_path, frames_dir, every, settings):
    """Pick frames into a staged folder and run SfM on them; the folder is committed later."""
    from fignetctl.core import sfm, video_frames
    from fignetctl.core.atomic import StagedDirectory

    staged = StagedDirectory(frames_dir, ("frame_*.png",))
    try:
        picks = video_frames.pick_frames(video_path, staged.path, every=every)
        cameras = sfm.run_sfm(staged.path, [p.name for p in picks], settings)
    except BaseException:
        staged.discard()
        raise
    return staged, cameras


def _imported(import_transforms, import_colmap, import_cameras, images_dir):
    """Cameras from a transforms.json, a COLMAP model or a cameras.npz, checked against --images."""
    from fignetctl.core import cameras as cameras_io
    from fignetctl.core import sfm

    if import_transforms is not None:
        cameras = cameras_io.import_transforms_json(import_transforms, image_dir=images_dir)
        where = str(import_transforms)
    elif import_colmap is not None:
        cameras, where = sfm.import_colmap(import_colmap), str(import_colmap)
    else:
        cameras, where = cameras_io.read_cameras(import_cameras), str(import_cameras)
    if images_dir is not None:
        cameras_io.check_images_match(cameras, images_dir, where)
    return cameras


def _relative_prefix(images_dir, json_dir) -> str:
    import os

    return os.path.relpath(Path(images_dir).resolve(), Path(json_dir).resolve()).replace(os.sep, "/") + "/"


def _summary(cameras, alignment) -> str:
    """The success line, and one line per candidate support plane when there are several."""
    line = (
        f"{len(cameras)} cameras, {len(cameras.points)} sparse points; up from {alignment.gravity_source}"
        + (
            f" ({alignment.plane_inliers} points on the support plane, now z = 0)"
            if alignment.plane_inliers
            else ""
        )
        + f"; scale from {alignment.scale_source}"
    )
    if len(alignment.planes) < 2:
        return line
    rows = [
        f"  {'->' if plane['chosen'] else '  '} z = {plane['height']:+.3f} m: {100 * plane['share']:.0f} % of the "
        f"points, {plane['extent'][0]:.2f} x {plane['extent'][1]:.2f} m"
        for plane in alignment.planes
    ]
    return "\n".join(
        [
            line,
            f"{len(rows)} horizontal planes (highest first; --support-plane largest|highest|lowest chooses):",
            *rows,
        ]
    )


def _provenance(images_dir, video_path, import_transforms, import_colmap, import_cameras) -> dict:
    """The stamp of cameras.npz: the video or images it was made from, and any imported poses."""
    from fignetctl.core.provenance import stamp

    source = {"video": video_path} if video_path is not None else {"images": images_dir}
    return stamp(**source, transforms=import_transforms, colmap=import_colmap, cameras=import_cameras)
