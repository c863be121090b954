"""Camera poses from images by structure from motion (pycolmap, CPU), and COLMAP import.

`run_sfm` extracts SIFT features, matches them (exhaustively for small unordered sets,
sequentially with a window for video frames), runs COLMAP's incremental mapper in a
temporary workspace and keeps the largest reconstruction. All images share one camera. With a
pinhole model (SIMPLE_PINHOLE, PINHOLE) the files on disk are the images the cameras describe;
with a distorted one (SIMPLE_RADIAL, RADIAL, OPENCV: phone photos) COLMAP estimates the lens
distortion with the poses and its undistorter writes pinhole copies of the images (cropped to
no blank pixels), which the returned cameras describe.

The result is a `Cameras` in COLMAP's arbitrary frame (no scale, no gravity);
`fignetctl.core.world_alignment` turns it into metres with z up.
"""

from __future__ import annotations

import dataclasses
import logging
import tempfile
from pathlib import Path

import numpy as np

from fignetctl.core.cameras import IMAGE_SUFFIXES, Cameras, validate
from fignetctl.core.media import read_image
from fignetctl.errors import FignetError, FormatError

log = logging.getLogger(__name__)

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
DISTORTED_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV")
CAMERA_MODELS = PINHOLE_MODELS + DISTORTED_MODELS
# Beyond this many images `matcher="auto"` matches sequentially instead of all pairs (measured on
# the bundled capture's video: 40 frames register 40/40 with all pairs, 32/40 sequentially).
AUTO_EXHAUSTIVE_MAX_IMAGES = 120


@dataclasses.dataclass(frozen=True)
class SfmSettings:
    """Settings of one structure-from-motion run."""

    matcher: str = "auto"
    """'exhaustive' (all pairs), 'sequential' (neighbours in name order) or 'auto'."""
    camera_model: str = "SIMPLE_PINHOLE"
    """One camera shared by all images: 'SIMPLE_PINHOLE' (f, cx, cy), 'PINHOLE' (fx, fy, cx, cy),
    or with lens distortion 'SIMPLE_RADIAL' (k), 'RADIAL' (k1, k2), 'OPENCV' (k1, k2, p1, p2)."""
    sequential_overlap: int = 10
    """Sequential matching: each image is matched with this many following images."""
    max_image_size: int = 1600
    """Images are downscaled to this longest side for feature extraction."""
    max_num_features: int = 8192
    """SIFT features per image."""
    peak_threshold: float = 0.0067
    """SIFT contrast threshold (COLMAP's default 0.0067; lower finds more, weaker features)."""
    domain_size_pooling: bool = False
    """DSP-SIFT descriptors (pooled over scales): more matches across wider baselines, slower."""
    guided_matching: bool = False
    """Match again guided by the two-view geometry: more inliers per pair."""
    init_min_num_inliers: int = 100
    """Incremental mapper: verified matches the initial image pair needs (COLMAP: 100)."""
    init_min_tri_angle: float = 16.0
    """Incremental mapper: triangulation angle (degrees) the initial pair needs (COLMAP: 16)."""
    abs_pose_min_num_inliers: int = 30
    """Incremental mapper: 2D-3D inliers an image needs to register (COLMAP: 30)."""
    min_registered_fraction: float = 0.8
    """Fewer registered images than this fraction (or fewer than 3) is an error."""
    num_threads: int = -1
    """CPU threads for COLMAP (-1: all)."""
    seed: int = 0
    """COLMAP's random seed (COLMAP is still not bit-for-bit deterministic with threads)."""

    def resolved_matcher(self, image_count: int) -> str:
        if self.matcher == "auto":
            return "exhaustive" if image_count <= AUTO_EXHAUSTIVE_MAX_IMAGES else "sequential"
        return self.matcher


PRESETS = {
    "default": SfmSettings(),
    # Measured on the bundled capture: registers 20 views 18° apart where "default" registers 4.
    "wide-baseline": SfmSettings(
        domain_size_pooling=True,
        guided_matching=True,
        init_min_num_inliers=50,
        init_min_tri_angle=8.0,
        abs_pose_min_num_inliers=15,
    ),
}


# ----------------------------------------------------------------------------- inputs


def list_images(image_dir) -> tuple[list[str], int, int]:
    """Sorted image names in `image_dir` and their common size (width, height).

    Raises a one-line FignetError for a missing or empty folder, an unreadable image or
    images of different sizes.
    """

    image_dir = Path(image_dir)
    if not image_dir.is_dir():
        raise FignetError(f"{image_dir}: not a folder of images")
    names = sorted(p.name for p in image_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise FignetError(f"{image_dir}: holds no images ({', '.join(IMAGE_SUFFIXES)})")
    sizes = {}
    for name in names:
        image = read_image(image_dir / name, hint="; remove it or replace it")
        sizes.setdefault((image.shape[1], image.shape[0]), name)
    if len(sizes) > 1:
        (size_a, first_a), (size_b, first_b) = list(sizes.items())[:2]
        raise FignetError(
            f"{image_dir}: images have different sizes ({first_a} is {size_a[0]}x{size_a[1]}, "
            f"{first_b} is {size_b[0]}x{size_b[1]}); one camera needs one image size"
        )
    (width, height), _ = next(iter(sizes.items()))
    return names, width, height


# ----------------------------------------------------------------------------- pycolmap


def _import_pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise FignetError("structure from motion needs pycolmap: pip install 'pycolmap>=4,<5'") from None
    # COLMAP errors only with -vv; our own log and FignetError say what happened.
    pycolmap.logging.minloglevel = 2 if log.isEnabledFor(logging.DEBUG) else 3
    return pycolmap


def _extract_and_match(pycolmap, database, image_dir, names, settings: SfmSettings) -> None:
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = settings.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = settings.max_image_size
    extraction.num_threads = settings.num_threads
    extraction.sift.max_num_features = settings.max_num_features
    extraction.sift.peak_threshold = settings.peak_threshold
    extraction.sift.domain_size_pooling = settings.domain_size_pooling
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = settings.num_threads
    matching.guided_matching = settings.guided_matching
    if settings.resolved_matcher(len(names)) == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = settings.sequential_overlap
        pycolmap.match_sequential(
            database, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu
        )
    else:
        pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)


def _map(pycolmap, database, image_dir, workspace: Path, settings: SfmSettings) -> dict:
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = settings.num_threads
    options.random_seed = settings.seed
    options.ba_refine_principal_point = False
    options.extract_colors = True
    options.mapper.init_min_num_inliers = settings.init_min_num_inliers
    options.mapper.init_min_tri_angle = settings.init_min_tri_angle
    options.mapper.abs_pose_min_num_inliers = settings.abs_pose_min_num_inliers
    output = workspace / "sparse"
    output.mkdir()
    return pycolmap.incremental_mapping(database, image_dir, output, options=options)


def run_sfm(
    image_dir,
    names: list[str] | None = None,
    settings: SfmSettings = SfmSettings(),
    undistorted_dir=None,
    keep_dir=None,
) -> Cameras:
    """Poses of the images in `image_dir` (all, or `names`) in COLMAP's arbitrary frame.

    With a distorted camera model the undistorted images are written into the existing folder
    `undistorted_dir` (required then) and the cameras describe them. `keep_dir`, an existing
    folder, receives the COLMAP workspace to open in COLMAP: database.db, sparse/0 (the model
    of the images as given) and points.ply (the sparse points). Raises FignetError, having
    written nothing, when fewer than `settings.min_registered_fraction` of the images (or
    fewer than 3) register.
    """
    pycolmap = _import_pycolmap()
    image_dir = Path(image_dir)
    if settings.camera_model not in CAMERA_MODELS:
        raise FignetError(f"camera model {settings.camera_model!r}: choose one of {', '.join(CAMERA_MODELS)}")
    distorted = settings.camera_model in DISTORTED_MODELS
    if distorted and undistorted_dir is None:
        raise ValueError("a distorted camera model needs a folder for the undistorted images")
    if names is None:
        names, _, _ = list_images(image_dir)
    matcher = settings.resolved_matcher(len(names))
    log.info(
        "structure from motion: %d images, %s matching, %s camera", len(names), matcher, settings.camera_model
    )
    with tempfile.TemporaryDirectory(prefix="fignetctl-sfm-") as workspace:
        workspace = Path(workspace)
        database = workspace / "database.db"
        try:
            _extract_and_match(pycolmap, database, image_dir, names, settings)
            reconstructions = _map(pycolmap, database, image_dir, workspace, settings)
        except (RuntimeError, ValueError) as error:
            raise FignetError(f"COLMAP failed on {image_dir}: {str(error).splitlines()[0]}") from None
        best = max(reconstructions.values(), key=lambda r: r.num_reg_images(), default=None)
        registered = 0 if best is None else best.num_reg_images()
        _check_registered(registered, len(names), matcher, settings)
        if keep_dir is not None:
            _keep_workspace(best, database, Path(keep_dir))
        if distorted:
            cameras = _undistort(pycolmap, best, image_dir, workspace, Path(undistorted_dir), names)
        else:
            cameras = reconstruction_to_cameras(best, order=names)
    log.info(
        "registered %d/%d images; %d sparse points; mean reprojection error %.2f px",
        registered,
        len(names),
        len(cameras.points),
        best.compute_mean_reprojection_error(),
    )
    return cameras


def _keep_workspace(reconstruction, database: Path, folder: Path) -> None:
    import shutil

    shutil.copyfile(database, folder / "database.db")
    (folder / "sparse" / "0").mkdir(parents=True)
    reconstruction.write(folder / "sparse" / "0")
    reconstruction.export_PLY(folder / "points.ply")


def _undistort(pycolmap, reconstruction, image_dir: Path, workspace: Path, out: Path, names) -> Cameras:
    """COLMAP's undistorter on the registered images: pinhole copies in `out`, their cameras."""
    import shutil

    model, undistorted = workspace / "distorted-model", workspace / "undistorted"
    model.mkdir()
    reconstruction.write(model)
    camera = next(iter(reconstruction.cameras.values()))
    log.info("lens: %s %s", camera.model_name, np.round(np.asarray(camera.params), 5).tolist())
    try:
        pycolmap.undistort_images(undistorted, model, image_dir)
    except (RuntimeError, ValueError) as error:
        raise FignetError(f"COLMAP could not undistort {image_dir}: {str(error).splitlines()[0]}") from None
    cameras = reconstruction_to_cameras(pycolmap.Reconstruction(undistorted / "sparse"), order=names)
    for name in cameras.image_names:
        shutil.copyfile(undistorted / "images" / str(name), out / str(name))
    return cameras


def _check_registered(registered: int, total: int, matcher: str, settings: SfmSettings) -> None:
    needed = max(3, int(np.ceil(settings.min_registered_fraction * total)))
    if registered >= needed:
        if registered < total:
            log.warning("only %d of %d images registered; the others get no camera", registered, total)
        return
    other = (
        "`matcher=exhaustive`" if matcher == "sequential" else "`matcher=sequential` for video-like sequences"
    )
    raise FignetError(
        f"only {registered} of {total} images registered (need {needed}); try photos with more overlap "
        f"between neighbours (each part of the scene in 3+ views), more texture in the scene, fewer blurred "
        f"images, or {other}"
    )


# ----------------------------------------------------------------------------- conversion


def reconstruction_to_cameras(reconstruction, order: list[str] | None = None) -> Cameras:
    """A pycolmap.Reconstruction as Cameras: OpenCV c2w, per-image K, points and colours.

    Images come in `order` (names not registered are skipped), else sorted by name. All
    cameras must have one image size; distortion parameters, if any, are dropped with a
    warning (a pinhole K cannot hold them).
    """
    images = {image.name: image for image in reconstruction.images.values() if image.has_pose}
    if not images:
        raise FignetError("the reconstruction has no registered images")
    names = [n for n in order if n in images] if order is not None else sorted(images)
    K, c2w, sizes = [], [], set()
    for name in names:
        image = images[name]
        camera = reconstruction.cameras[image.camera_id]
        K.append(_pinhole_K(camera))
        sizes.add((camera.width, camera.height))
        w2c = np.eye(4)
        w2c[:3, :] = image.cam_from_world().matrix()
        c2w.append(np.linalg.inv(w2c))
    if len(sizes) > 1:
        raise FormatError(
            f"the reconstruction's cameras have different image sizes {sorted(sizes)}; fignetctl needs one size"
        )
    points, colors = _sparse_points(reconstruction)
    width, height = sizes.pop()
    c2w = np.array(c2w)
    c2w[:, 3] = [0, 0, 0, 1]
    return validate(
        Cameras(np.array(names), np.array(K), c2w, width, height, points, colors), "reconstruction"
    )


def _pinhole_K(camera) -> np.ndarray:
    """K of a camera; a FormatError for one with lens distortion (cameras.npz is pinhole)."""
    if camera.model_name not in PINHOLE_MODELS:
        extra = (
            np.asarray(camera.params)[list(camera.extra_params_idxs())] if camera.extra_params_idxs() else []
        )
        if np.any(np.abs(extra) > 1e-6):
            raise FormatError(
                f"camera {camera.camera_id} is {camera.model_name} with distortion "
                f"{np.round(extra, 4).tolist()} and cameras.npz is pinhole; undistort the images first "
                "(colmap image_undistorter writes them with a PINHOLE model) and import that model"
            )
    return np.asarray(camera.calibration_matrix(), np.float64)


def _sparse_points(reconstruction) -> tuple[np.ndarray, np.ndarray]:
    points = reconstruction.points3D
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    xyz = np.array([p.xyz for p in points.values()], np.float64)
    colors = np.array([p.color for p in points.values()], np.uint8)
    return xyz, colors


def import_colmap(model_dir) -> Cameras:
    """Cameras from a COLMAP sparse model folder (cameras/images/points3D as .bin or .txt)."""
    pycolmap = _import_pycolmap()
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise FormatError(f"{model_dir}: not a COLMAP sparse model folder")
    has_bin = all((model_dir / f"{part}.bin").is_file() for part in ("cameras", "images"))
    has_txt = all((model_dir / f"{part}.txt").is_file() for part in ("cameras", "images"))
    if not (has_bin or has_txt):
        raise FormatError(
            f"{model_dir}: no cameras.bin/images.bin (or .txt); is it a COLMAP sparse model, e.g. sparse/0?"
        )
    try:
        reconstruction = pycolmap.Reconstruction(model_dir)
    except (RuntimeError, ValueError, OSError) as error:
        raise FormatError(
            f"{model_dir}: not a readable COLMAP model ({str(error).splitlines()[0]})"
        ) from None
    return reconstruction_to_cameras(reconstruction)


# ----------------------------------------------------------------------------- rerun


def log_cameras_to_rerun(path_rrd, cameras: Cameras, image_dir=None, entity_root: str = "world") -> Path:
    """Write the cameras (frusta, with their images when `image_dir` is given) and the sparse
    points to a rerun recording (.rrd), atomically. World: z up."""
    from fignetctl.core.rerun_log import recording

    path_rrd = Path(path_rrd)
    with recording(path_rrd) as (rr, rec):
        rec.log(entity_root, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if len(cameras.points):
            rec.log(
                f"{entity_root}/points",
                rr.Points3D(cameras.points, colors=cameras.point_colors, radii=-2.0),
                static=True,
            )
        for index, name in enumerate(cameras.image_names):
            entity = f"{entity_root}/cameras/{index:04d}"
            c2w = cameras.c2w[index]
            rec.log(entity, rr.Transform3D(translation=c2w[:3, 3], mat3x3=c2w[:3, :3]), static=True)
            rec.log(
                entity,
                rr.Pinhole(image_from_camera=cameras.K[index], resolution=[cameras.width, cameras.height]),
                static=True,
            )
            file = Path(image_dir) / str(name) if image_dir is not None else None
            if file is not None and file.is_file():
                rec.log(f"{entity}/image", rr.EncodedImage(path=file), static=True)
    return path_rrd
