"""Cameras (`cameras.npz`), format `fignetctl.cameras`, format_version 1, and transforms.json.

Layout (DESIGN.md): `image_names (N,)`, `K (N,3,3)`, `c2w (N,4,4)` camera-to-world in the
OpenCV convention (x right, y down, z forward), `width`, `height`, the sparse points
`points (M,3)` and `point_colors (M,3) uint8`, plus `format` and `format_version`. World units
and axes are whatever produced the file; after `capture-poses` aligns them: metres, z up.

transforms.json (nerfstudio / instant-ngp / NeRF-synthetic) uses the OpenGL camera convention
(x right, y up, z backward): c2w_gl = c2w_cv · diag(1, −1, −1, 1), the same flip both ways.
Intrinsics are `fl_x, fl_y, cx, cy, w, h` at the top level or per frame, or only
`camera_angle_x` (NeRF-synthetic), which gives fl = w / (2 · tan(angle / 2)) and the centre
in the middle of the image.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from fignetctl.core.atomic import write_json
from fignetctl.core.containers import read_npz_document, require_regular_file, write_npz_document
from fignetctl.core.media import read_image
from fignetctl.core.pinhole import Camera
from fignetctl.errors import FormatError

FORMAT = "fignetctl.cameras"
FORMAT_VERSION = 1
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


@dataclasses.dataclass
class Cameras:
    """N pinhole cameras of one size, and the sparse points seen by them."""

    image_names: np.ndarray  # (N,) str, paths relative to the image folder
    K: np.ndarray  # (N, 3, 3) float64
    c2w: np.ndarray  # (N, 4, 4) float64, OpenCV convention
    width: int
    height: int
    points: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))  # (M, 3)
    point_colors: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros((0, 3), np.uint8)
    )  # (M, 3) uint8

    def __len__(self) -> int:
        return len(self.image_names)

    @property
    def centres(self) -> np.ndarray:
        """(N, 3) camera centres in world coordinates."""
        return self.c2w[:, :3, 3]

    def subset(self, indices) -> Cameras:
        """The cameras at `indices` (the sparse points are kept)."""
        indices = np.asarray(indices)
        return dataclasses.replace(
            self, image_names=self.image_names[indices], K=self.K[indices], c2w=self.c2w[indices]
        )

    def camera(self, index: int) -> Camera:
        """The pinhole camera of view `index`."""
        return Camera(self.K[index], self.c2w[index], self.width, self.height)

    def index_of(self, name: str) -> int:
        """Index of an image by its name (or by its file name without folders)."""
        names = [str(n) for n in self.image_names]
        if name in names:
            return names.index(name)
        stems = [Path(n).name for n in names]
        if name in stems:
            return stems.index(name)
        raise FormatError(f"no camera for image {name!r} (the cameras have {len(names)} images)")


def validate(cameras: Cameras, where: str = "cameras") -> Cameras:
    """Check shapes, finiteness and rotations; return the cameras with canonical dtypes."""
    n = len(cameras.image_names)
    names = np.asarray(cameras.image_names).astype(str)
    K, c2w = _real_array(cameras.K, "K", where), _real_array(cameras.c2w, "c2w", where)
    points = _real_array(cameras.points, "points", where)
    colors = _real_array(cameras.point_colors, "point_colors", where)
    if points.size % 3 or colors.size % 3:
        raise FormatError(f"{where}: 'points' and 'point_colors' must have shape (M, 3)")
    points, colors = points.reshape(-1, 3), colors.reshape(-1, 3)
    if n == 0:
        raise FormatError(f"{where}: holds no cameras")
    if K.shape != (n, 3, 3):
        raise FormatError(f"{where}: 'K' has shape {K.shape}, expected ({n}, 3, 3)")
    if c2w.shape != (n, 4, 4):
        raise FormatError(f"{where}: 'c2w' has shape {c2w.shape}, expected ({n}, 4, 4)")
    for field, value in (("K", K), ("c2w", c2w), ("points", points)):
        bad = ~np.isfinite(value)
        if bad.any():
            first = np.argwhere(bad)[0]
            raise FormatError(
                f"{where}: '{field}' holds NaN or inf (first at index {tuple(int(i) for i in first)})"
            )
    width, height = int(cameras.width), int(cameras.height)
    if width <= 0 or height <= 0:
        raise FormatError(f"{where}: image size {width}x{height} is not positive")
    if (K[:, 0, 0] <= 0).any() or (K[:, 1, 1] <= 0).any():
        raise FormatError(f"{where}: 'K' has a focal length that is not positive")
    rotations = c2w[:, :3, :3]
    orthogonality = np.abs(np.einsum("nji,njk->nik", rotations, rotations) - np.eye(3)).max(axis=(1, 2))
    if (orthogonality > 1e-4).any() or (np.linalg.det(rotations) < 0).any():
        worst = int(np.argmax(orthogonality))
        raise FormatError(
            f"{where}: 'c2w' of camera {worst} ({names[worst]}) is not a rotation and a translation"
        )
    if len(colors) != len(points):
        raise FormatError(f"{where}: {len(points)} points but {len(colors)} point colours")
    if colors.size and (colors.min() < 0 or colors.max() > 255):
        raise FormatError(f"{where}: 'point_colors' must lie in 0..255")
    return Cameras(names, K, c2w, width, height, points, colors.astype(np.uint8))


def _real_array(value, field: str, where: str) -> np.ndarray:
    """`value` as float64, or a FormatError naming the field (strings, complex, objects)."""
    value = np.asarray(value)
    if value.dtype.kind not in "biuf":
        raise FormatError(f"{where}: {field!r} must hold real numbers, got {value.dtype}")
    return value.astype(np.float64)


def write_cameras(path, cameras: Cameras, provenance: dict | None = None) -> None:
    """Validate, then write `cameras.npz` atomically, stamped with `provenance` (provenance.stamp;
    default: the version alone)."""
    cameras = validate(cameras, str(path))
    arrays = {
        "image_names": cameras.image_names,
        "K": cameras.K,
        "c2w": cameras.c2w,
        "width": np.array(cameras.width),
        "height": np.array(cameras.height),
        "points": cameras.points,
        "point_colors": cameras.point_colors,
    }
    write_npz_document(path, FORMAT, FORMAT_VERSION, arrays, provenance)


def read_cameras(path) -> Cameras:
    """Read and check `cameras.npz`; any problem is a FormatError naming the file and field."""
    path = Path(path)
    arrays = read_npz_document(
        path, "cameras.npz", FORMAT, FORMAT_VERSION, ("image_names", "K", "c2w", "width", "height")
    )
    try:
        cameras = Cameras(
            image_names=arrays["image_names"],
            K=arrays["K"],
            c2w=arrays["c2w"],
            width=int(arrays["width"]),
            height=int(arrays["height"]),
            points=arrays.get("points", np.zeros((0, 3))),
            point_colors=arrays.get("point_colors", np.zeros((0, 3), np.uint8)),
        )
    except (TypeError, ValueError) as error:
        raise FormatError(f"{path}: a field has the wrong type ({error})") from None
    return validate(cameras, str(path))


def check_images_match(cameras: Cameras, image_dir, where: str = "cameras") -> list[Path]:
    """The image files of the cameras in `image_dir`, checked to exist and to have the cameras'
    size; a FormatError says which image does not match."""

    image_dir = Path(image_dir)
    files = []
    for name in cameras.image_names:
        file = image_dir / str(name)
        if not file.is_file():
            raise FormatError(
                f"{where}: image {name!r} is not in {image_dir}; are these the images the cameras were made from?"
            )
        image = read_image(file)
        if image.shape[:2] != (cameras.height, cameras.width):
            raise FormatError(
                f"{file}: is {image.shape[1]}x{image.shape[0]} but the cameras are "
                f"{cameras.width}x{cameras.height}; the images and {where} do not match"
            )
        files.append(file)
    return files


# transforms.json -------------------------------------------------------------------------


def export_transforms_json(path, cameras: Cameras, image_prefix: str = "") -> None:
    """Write nerfstudio / instant-ngp transforms.json (OpenGL poses, per-frame intrinsics)."""
    frames = []
    for name, K, c2w in zip(cameras.image_names, cameras.K, cameras.c2w):
        frames.append(
            {
                "file_path": f"{image_prefix}{name}",
                "transform_matrix": (c2w @ OPENCV_TO_OPENGL).tolist(),
                "fl_x": float(K[0, 0]),
                "fl_y": float(K[1, 1]),
                "cx": float(K[0, 2]),
                "cy": float(K[1, 2]),
            }
        )
    document = {"camera_model": "OPENCV", "w": cameras.width, "h": cameras.height, "frames": frames}
    write_json(path, document)


def import_transforms_json(path, image_dir=None) -> Cameras:
    """Read transforms.json; image names are relative to `image_dir` (default: the json's
    folder). Sizes missing from the json are read from the first image. The sparse points come
    from the PLY named by `ply_file_path` (nerfstudio's COLMAP export), in the poses' frame."""
    path = require_regular_file(path)
    try:
        document = json.loads(path.read_text())
        frames = document["frames"]
        if not isinstance(frames, list) or not frames:
            raise ValueError("'frames' is empty")
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file") from None
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError) as error:
        raise FormatError(f"{path}: not a transforms.json ({type(error).__name__}: {error})") from None
    base = path.parent
    image_dir = base if image_dir is None else Path(image_dir)
    names, Ks, c2ws, sizes = [], [], [], []
    for index, frame in enumerate(frames):
        where = f"{path}: frame {index}"
        try:
            file = _resolve_frame_file(base, str(frame["file_path"]))
            matrix = np.asarray(frame["transform_matrix"], np.float64)
            if matrix.shape == (3, 4):
                matrix = np.vstack([matrix, [0, 0, 0, 1]])
            if matrix.shape != (4, 4):
                raise ValueError(f"transform_matrix has shape {matrix.shape}")
            if not np.isfinite(matrix).all():
                raise ValueError("transform_matrix holds NaN or infinite numbers")
            intrinsics = {**document, **frame}
            _refuse_distortion(intrinsics, where)
            width, height = _frame_size(intrinsics, file)
            K = _frame_K(intrinsics, width, height)
        except (KeyError, TypeError, ValueError) as error:
            raise FormatError(f"{where}: {type(error).__name__}: {error}") from None
        try:
            names.append(str(file.resolve().relative_to(image_dir.resolve())))
        except ValueError:
            raise FormatError(f"{where}: image {file} is not inside {image_dir}") from None
        Ks.append(K)
        c2ws.append(matrix @ OPENCV_TO_OPENGL)
        sizes.append((width, height))
    if len(set(sizes)) > 1:
        raise FormatError(
            f"{path}: the frames have different image sizes {sorted(set(sizes))}; fignetctl needs one size"
        )
    # Some exporters scale the rotation part; keep only the rotation.
    c2ws = np.array(c2ws)
    u, _, vt = np.linalg.svd(c2ws[:, :3, :3])
    c2ws[:, :3, :3] = u @ vt
    width, height = sizes[0]
    points, colors = _ply_points(document, path)
    return validate(Cameras(np.array(names), np.array(Ks), c2ws, width, height, points, colors), str(path))


def _ply_points(document: dict, path: Path) -> tuple:
    """(M, 3) points and (M, 3) uint8 colours of transforms.json's `ply_file_path` (relative to
    the json), or none when it names no file."""
    name = document.get("ply_file_path")
    if not name:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    import trimesh

    file = require_regular_file(path.parent / str(name), "PLY")
    try:
        cloud = trimesh.load(file, file_type="ply", process=False)
        points = np.asarray(cloud.vertices, np.float64)
        colors = getattr(getattr(cloud, "visual", None), "vertex_colors", None)
        if colors is None or len(colors) != len(points):
            colors = getattr(cloud, "colors", None)
    except Exception as error:  # trimesh raises many types on a damaged file
        raise FormatError(
            f"{path}: ply_file_path {name!r} is not a readable PLY ({type(error).__name__})"
        ) from None
    if points.ndim != 2 or points.shape[1:] != (3,) or not np.isfinite(points).all():
        raise FormatError(f"{path}: ply_file_path {name!r} holds no finite (M, 3) points")
    colors = (
        np.asarray(colors, np.uint8)[:, :3] if colors is not None and len(colors) == len(points) else None
    )
    return points, colors if colors is not None else np.full((len(points), 3), 128, np.uint8)


DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def _refuse_distortion(intrinsics: dict, where: str) -> None:
    """A FormatError for a frame whose lens distortion is not zero: cameras.npz is pinhole, and
    keeping the poses while dropping k1... would bend every ray by the distortion."""
    nonzero = {key: intrinsics[key] for key in DISTORTION_KEYS if float(intrinsics.get(key) or 0.0) != 0.0}
    if nonzero or str(intrinsics.get("camera_model", "OPENCV")).upper() not in (
        "OPENCV",
        "PINHOLE",
        "SIMPLE_PINHOLE",
    ):
        shown = ", ".join(f"{key}={value}" for key, value in nonzero.items()) or intrinsics.get(
            "camera_model"
        )
        raise FormatError(
            f"{where}: the images are distorted ({shown}) and cameras.npz is pinhole; undistort them first "
            "(e.g. colmap image_undistorter, or nerfstudio's ns-process-data) and import the undistorted ones"
        )


def _resolve_frame_file(base: Path, file_path: str) -> Path:
    file = base / file_path
    if file.suffix.lower() in IMAGE_SUFFIXES:
        return file
    for suffix in IMAGE_SUFFIXES:  # NeRF-synthetic leaves the extension out
        if file.with_name(file.name + suffix).is_file():
            return file.with_name(file.name + suffix)
    return file


def _frame_size(intrinsics: dict, file: Path) -> tuple[int, int]:
    if "w" in intrinsics and "h" in intrinsics:
        return int(intrinsics["w"]), int(intrinsics["h"])
    try:
        image = read_image(file)
    except FormatError:
        raise ValueError(f"no 'w'/'h' and the image {file} cannot be read for its size") from None
    return image.shape[1], image.shape[0]


def _frame_K(intrinsics: dict, width: int, height: int) -> np.ndarray:
    if "fl_x" in intrinsics:
        fx = float(intrinsics["fl_x"])
        fy = float(intrinsics.get("fl_y", fx))
    elif "camera_angle_x" in intrinsics:
        fx = width / (2.0 * math.tan(float(intrinsics["camera_angle_x"]) / 2.0))
        fy = (
            height / (2.0 * math.tan(float(intrinsics["camera_angle_y"]) / 2.0))
            if "camera_angle_y" in intrinsics
            else fx
        )
    else:
        raise ValueError("no intrinsics: neither 'fl_x' nor 'camera_angle_x'")
    cx = float(intrinsics.get("cx", width / 2.0))
    cy = float(intrinsics.get("cy", height / 2.0))
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
