"""`fignetctl capture-poses`: a folder of images or a video -> cameras.npz (metres, z up)."""

import click

from fignetctl.commands import options
from fignetctl.stages import capture_poses as stage

PATH = options.path_option


@click.command("capture-poses")
@PATH("--images", folder=True, help="Folder of photographs (one size); with --import-*, the ones to check.")
@PATH("--video", help="A video; frames are picked with --every and written to --frames-dir.")
@PATH("--frames-dir", folder=True, help="Video: where the picked frames go.  [default: images/ beside -o]")
@PATH("--import-transforms", help="Poses from a transforms.json (nerfstudio / instant-ngp), not COLMAP.")
@PATH("--import-colmap", folder=True, help="Poses from a COLMAP sparse model folder (.bin or .txt files).")
@PATH("--import-cameras", help="Re-align or convert an existing cameras.npz.")
@PATH("--undistorted-dir", folder=True, help="Distorted --camera-model: the undistorted images' folder.")
@PATH("--keep-colmap", folder=True, help="Keep COLMAP's workspace here: database.db, sparse/0, points.ply.")
@PATH("--export-transforms", help="Also write a transforms.json (OpenGL convention).")
@PATH("-o", "--output", required=True, help="cameras.npz to write.")
@options.settings_options(
    stage.Settings, baseline={"type": (str, str, options.FiniteFloatRange(0, min_open=True))}
)
@options.rerun_option
@options.json_option
@options.overwrite_option
def capture_poses(output, json_path, overwrite, **values):
    """Camera poses of a folder of images or a video, in metres with z up (cameras.npz).

    COLMAP (pycolmap, CPU) finds the poses with one shared camera (a distorted one's images are
    undistorted); up comes from the support plane in the sparse points (moved to z = 0), the
    scale from one length you measured: the mean camera height above that plane
    (--camera-height, default 0.5 m) or the distance between two cameras (--baseline). Nothing
    is written when too few images register. Prints the output path. See docs/capture-poses.md.

    \b
    Example:
      fignetctl capture-poses --images capture/images --camera-height 0.45 -o capture/cameras.npz
      fignetctl capture-poses --video table.mp4 --every 8 -o table/cameras.npz --rerun table/poses.rrd
      fignetctl capture-poses --import-colmap sparse/0 --images images --gravity plane -o cameras.npz
    """
    settings, output = options.settings_from(stage.Settings, values), options.output_path(output, overwrite)
    json_path = options.optional_output(json_path, overwrite, "--json")
    for key, default in stage.default_folders(output, settings, values["video"]).items():
        values[key] = values[key] or default
    for key in ("export_transforms", "rerun_path", "frames_dir", "undistorted_dir", "keep_colmap"):
        flag = "--" + key.removesuffix("_path").replace("_", "-")
        values[key] = options.optional_output(values[key], overwrite, flag)
    summary = stage.run(output, settings, **values, json_path=json_path)
    click.echo(summary["message"], err=True)
    click.echo(str(output))
