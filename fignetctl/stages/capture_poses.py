"""capture-poses: a folder of images or a video -> cameras.npz (metres, z up)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from fignetctl.errors import SettingError
from fignetctl.stages import check, setting, write_summary

SOURCES_ERROR = (
    "give one input: --images DIR, --video FILE, or one of --import-transforms/--import-colmap/"
    "--import-cameras (with --images to check them)"
)


@dataclasses.dataclass(frozen=True)
class Settings:
    every: int = setting(10, "Video: keep the sharpest frame of each run of N frames.", low=1, high=10**5)
    matcher: str = setting(
        "auto",
        "Feature matching: all pairs, or neighbours in name order; auto: all pairs up to 120 images.",
        choices=("auto", "exhaustive", "sequential"),
    )
    camera_model: str = setting(
        "SIMPLE_PINHOLE",
        "One camera shared by all images; with lens distortion (SIMPLE_RADIAL, RADIAL, OPENCV: phone "
        "photos) the images are undistorted into --undistorted-dir, which the cameras describe.",
        choices=("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"),
    )
    gravity: str = setting(
        "auto",
        "Up from the support plane in the sparse points, the cameras' mean up, auto (plane, else cameras), "
        "or none (keep the input's frame and scale).",
        choices=("auto", "plane", "cameras", "none"),
    )
    support_plane: str = setting(
        "auto",
        "Of several horizontal planes (a table on a floor), the support (z = 0; --camera-height is "
        "measured from it): auto (the plane under what the cameras look at, else the largest), "
        "the one with the most points, the highest or the lowest.",
        choices=("auto", "largest", "highest", "lowest"),
    )
    camera_height: float | None = setting(
        None,
        "Scale: measured mean height (m) of the camera centres above the support plane.  [default: 0.5]",
        low=0,
        low_open=True,
    )
    baseline: tuple[str, str, float] | None = setting(
        None,
        "Scale: measured distance between the cameras of two images (instead of --camera-height).",
        metavar="IMAGE_A IMAGE_B METRES",
    )
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)


def run(
    output,
    settings: Settings = Settings(),
    *,
    images=None,
    video=None,
    frames_dir=None,
    import_transforms=None,
    import_colmap=None,
    import_cameras=None,
    undistorted_dir=None,
    keep_colmap=None,
    export_transforms=None,
    rerun_path=None,
    json_path=None,
) -> dict:
    """Camera poses of the folder `images`, of a `video` (its picked frames written to
    `frames_dir`, by default images/ beside `output`) or imported (`import_transforms`,
    `import_colmap` or `import_cameras`, checked against `images` when given), aligned to
    metres with z up and written to `output` (cameras.npz). With a distorted camera model the
    undistorted images go to `undistorted_dir` (default_folders gives the defaults);
    `keep_colmap` keeps COLMAP's workspace (database, sparse/0, points.ply). Optionally a transforms.json
    (`export_transforms`), a rerun recording and the --json summary. Returns the summary with
    a `message` (the success line, and the support planes found when there are several)."""
    from fignetctl.core import sfm, video_frames, world_alignment
    from fignetctl.core.atomic import StagedDirectory
    from fignetctl.core.cameras import export_transforms_json, write_cameras

    check(settings)
    paths = (images, video, import_transforms, import_colmap, import_cameras)
    images_dir, video_path, import_transforms, import_colmap, import_cameras = (
        None if path is None else Path(path) for path in paths
    )
    given = [
        path for path in (video_path, import_transforms, import_colmap, import_cameras) if path is not None
    ]
    if len(given) > 1 or (video_path is not None and images_dir is not None) or not (given or images_dir):
        raise SettingError(SOURCES_ERROR)
    if settings.camera_height is not None and settings.baseline is not None:
        raise SettingError("--camera-height and --baseline both set the scale; give one")
    _check_baseline(settings.baseline)
    output = Path(output)
    sfm_settings = sfm.SfmSettings(
        matcher=settings.matcher, camera_model=settings.camera_model, seed=settings.seed
    )
    alignment_settings = world_alignment.AlignmentSettings(
        gravity=settings.gravity,
        camera_height=settings.camera_height,
        baseline=None if settings.baseline is None else tuple(settings.baseline),
        seed=settings.seed,
        support_plane=settings.support_plane,
    )

    if given and not video_path and (keep_colmap or settings.camera_model in sfm.DISTORTED_MODELS):
        raise SettingError("--camera-model and --keep-colmap apply to COLMAP runs, not to --import-*")
    defaults = default_folders(output, settings, video_path)
    frames_dir, undistorted_dir = (
        frames_dir or defaults["frames_dir"],
        undistorted_dir or defaults["undistorted_dir"],
    )
    source = images_dir
    staged = {}  # folders committed once cameras.npz is written
    try:
        if given and video_path is None:
            cameras = _imported(import_transforms, import_colmap, import_cameras, images_dir)
        else:
            names = None
            if video_path is not None:
                staged["frames"] = StagedDirectory(frames_dir, ("frame_*.png",))
                picks = video_frames.pick_frames(video_path, staged["frames"].path, every=settings.every)
                source, images_dir, names = staged["frames"].path, Path(frames_dir), [p.name for p in picks]
            for key, folder, owned in (
                ("undistorted", undistorted_dir, IMAGE_PATTERNS),
                ("colmap", keep_colmap, ("database.db", "sparse", "points.ply")),
            ):
                if folder is not None:
                    staged[key] = StagedDirectory(folder, owned)
            cameras = sfm.run_sfm(
                source,
                names,
                sfm_settings,
                undistorted_dir=staged["undistorted"].path if "undistorted" in staged else None,
                keep_dir=staged["colmap"].path if "colmap" in staged else None,
            )
        aligned, alignment = world_alignment.align(cameras, alignment_settings)
        provenance = _provenance(images_dir, video_path, import_transforms, import_colmap, import_cameras)
        write_cameras(output, aligned, provenance)
        for folder in staged.values():
            folder.commit()
    finally:
        for folder in staged.values():
            folder.discard()
    if "undistorted" in staged:
        images_dir = Path(undistorted_dir)  # the images the cameras describe
    summary = {
        "output": str(output),
        "images": None if images_dir is None else str(images_dir),
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
        export_transforms = Path(export_transforms)
        prefix = "" if images_dir is None else _relative_prefix(images_dir, export_transforms.parent)
        export_transforms_json(export_transforms, aligned, image_prefix=prefix)
    if rerun_path is not None:
        sfm.log_cameras_to_rerun(rerun_path, aligned, images_dir)
    message = _summary(aligned, alignment)
    if "undistorted" in staged:
        message += f"\nundistorted images ({aligned.width}x{aligned.height}, pinhole) in {images_dir}: fit the NeRF on them"
    return {**summary, "message": message}


IMAGE_PATTERNS = ("*.png", "*.jpg", "*.jpeg", "*.PNG", "*.JPG", "*.JPEG")


def default_folders(output, settings: Settings, video=None) -> dict:
    """Where a video's picked frames go (images/ beside `output`) and, with a distorted camera
    model, the undistorted images (images_undistorted/ beside it); None where not written."""
    from fignetctl.core.sfm import DISTORTED_MODELS

    parent = Path(output).parent
    return {
        "frames_dir": parent / "images" if video is not None else None,
        "undistorted_dir": parent / "images_undistorted"
        if settings.camera_model in DISTORTED_MODELS
        else None,
    }


def _check_baseline(baseline) -> None:
    """A baseline is (image_a, image_b, metres) with a finite, positive length (as --baseline parses)."""
    if baseline is None:
        return
    try:
        _, _, metres = baseline
        metres = float(metres)
    except (TypeError, ValueError):
        raise SettingError(f"baseline = {baseline!r}: give (image_a, image_b, metres)") from None
    if not (math.isfinite(metres) and metres > 0):
        raise SettingError(f"baseline = {baseline!r}: the length must be a finite number of metres above 0")


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
            f"{len(rows)} horizontal planes (highest first; --support-plane auto|largest|highest|lowest chooses):",
            *rows,
        ]
    )


def _provenance(images_dir, video_path, import_transforms, import_colmap, import_cameras) -> dict:
    """The stamp of cameras.npz: the video or images it was made from, and any imported poses."""
    from fignetctl.core.provenance import stamp

    source = {"video": video_path} if video_path is not None else {"images": images_dir}
    return stamp(**source, transforms=import_transforms, colmap=import_colmap, cameras=import_cameras)
