"""Metres and z up for cameras from structure from motion (the physics needs both).

Conventions (docs/capture-poses.md):
- Up: the normal of the support plane in the sparse points (RANSAC, among planes within 45°
  of the cameras' mean up vector; then the horizontal planes parallel to it, each the largest
  connected patch of a height band refit with a tight threshold, and the one --support-plane
  chooses: by default the one under what the cameras look at), oriented toward the cameras; or, as a
  fallback or on request, the cameras' mean up vector (-y of OpenCV cameras: a photographer
  mostly holds the camera level).
- Origin: the centroid of the plane's inlier points, moved onto the plane, so the support
  plane is z = 0. With the camera up vector, the support height is the densest height band
  of the points below the cameras, or, with no points, the point the cameras look at (the
  point nearest to all optical axes).
- Yaw: the smallest rotation taking the up vector to +z (the horizontal axes follow COLMAP's).
- Scale: from one length the user measured — the mean height of the camera centres above
  the support plane (default 0.5 m), or the distance between two cameras.

Everything is a similarity x' = s · R · (x − origin), applied to cameras and points alike.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from fignetctl.core.cameras import Cameras
from fignetctl.errors import FignetError

log = logging.getLogger(__name__)

DEFAULT_CAMERA_HEIGHT = 0.5  # metres: a hand-held camera looking down at a table top
MAX_PLANE_TILT_DEG = 45.0  # planes steeper than this from the cameras' up are walls
MIN_PLANE_INLIER_FRACTION = 0.15
MIN_CANDIDATE_FRACTION = 0.05  # a parallel plane holding this share of the points is a candidate
MIN_PLANE_FILL = 0.4  # a candidate's points must cover this share of their box (_area_filled)
SUPPORT_CHOICES = ("auto", "largest", "highest", "lowest")
CLUSTER_LINK = 3.0  # points within this many times their typical spacing belong to one patch
PLANE_REFINE_TOLERANCE = 0.01  # refit inliers: within this share of the distance to the cameras
PLANE_TILT_REFINE_DEG = 20.0  # the refit plane stays this close to the band it came from
LOOKED_AT_BELOW = 0.05  # 'auto': the looked-at point may lie this share of a plane's size below it


@dataclasses.dataclass(frozen=True)
class AlignmentSettings:
    """How capture-poses puts the cameras into metres with z up."""

    gravity: str = "auto"
    """'plane' (support plane normal), 'cameras' (mean camera up), 'auto' (plane, else cameras), 'none'."""
    camera_height: float | None = None
    """Measured mean height (m) of the camera centres above the support plane."""
    baseline: tuple | None = None
    """(image_a, image_b, metres): the measured distance between two camera centres."""
    plane_threshold: float = 0.01
    """RANSAC inlier distance as a fraction of the scene size (points' 5–95% extent)."""
    ransac_iterations: int = 1000
    """RANSAC plane hypotheses."""
    seed: int = 0
    """RANSAC's random seed."""
    support_plane: str = "auto"
    """Which of the horizontal planes in the points (parallel_planes) is the support: 'auto' (the
    highest one under the point the cameras look at, else the largest), 'largest' (the one holding
    the most points), 'highest' or 'lowest'."""


@dataclasses.dataclass
class Alignment:
    """The similarity x' = scale · rotation · (x − origin) and how it was found."""

    scale: float
    rotation: np.ndarray  # (3, 3)
    origin: np.ndarray  # (3,)
    gravity_source: str  # 'plane', 'cameras' or 'none'
    scale_source: str
    plane_inliers: int = 0
    planes: tuple = ()
    """The candidate support planes, parallel to the chosen one: dicts of height (m, above the
    chosen plane after scaling), share (of the sparse points), extent (m, x and y of the
    middle 90 % of their points) and chosen (bool); highest first."""

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous matrix of the similarity."""
        matrix = np.eye(4)
        matrix[:3, :3] = self.scale * self.rotation
        matrix[:3, 3] = -self.scale * self.rotation @ self.origin
        return matrix


# ----------------------------------------------------------------------------- geometry


def umeyama(source, target, with_scale=True):
    """Similarity (s, R, t) minimising Σ‖s·R·source_i + t − target_i‖² (Umeyama 1991).

    source, target : (n, 3) float, n ≥ 3 points not all on a line
    """
    source, target = np.asarray(source, float), np.asarray(target, float)
    mean_source, mean_target = source.mean(axis=0), target.mean(axis=0)
    centred_source, centred_target = source - mean_source, target - mean_target
    covariance = centred_target.T @ centred_source / len(source)
    u, singular_values, vt = np.linalg.svd(covariance)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ sign @ vt
    variance = (centred_source**2).sum() / len(source)
    scale = float((singular_values * np.diag(sign)).sum() / variance) if with_scale else 1.0
    translation = mean_target - scale * rotation @ mean_source
    return scale, rotation, translation


def rotation_between(a, b) -> np.ndarray:
    """(3, 3) smallest rotation taking unit vector `a` to unit vector `b` (Rodrigues)."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    sine, cosine = np.linalg.norm(axis), float(a @ b)
    if sine < 1e-12:
        if cosine > 0:
            return np.eye(3)
        perpendicular = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        perpendicular /= np.linalg.norm(perpendicular)
        return 2 * np.outer(perpendicular, perpendicular) - np.eye(3)  # 180° about it
    axis /= sine
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + sine * cross + (1 - cosine) * cross @ cross


def fit_plane_least_squares(points):
    """(normal, centroid) of the total-least-squares plane through (n, 3) points."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    return vt[2], centroid


def fit_plane_ransac(points, threshold, iterations=1000, seed=0, allowed=None):
    """The plane with the most points within `threshold`, refit to its inliers.

    points : (n, 3) float
    allowed : optional function normal -> bool that rejects hypotheses (e.g. walls)
    Returns (normal, centroid of inliers, inlier mask), or None with fewer than 3 points or
    no allowed plane.
    """
    points = np.asarray(points, float)
    if len(points) < 3:
        return None
    rng = np.random.default_rng(seed)
    samples = rng.integers(0, len(points), size=(iterations, 3))
    a, b, c = points[samples[:, 0]], points[samples[:, 1]], points[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    lengths = np.linalg.norm(normals, axis=1)
    best_mask, best_count = None, 0
    for normal, length, anchor in zip(normals, lengths, a):
        if length < 1e-12:
            continue
        normal = normal / length
        if allowed is not None and not allowed(normal):
            continue
        mask = np.abs((points - anchor) @ normal) < threshold
        count = int(mask.sum())
        if count > best_count:
            best_mask, best_count = mask, count
    if best_mask is None or best_count < 3:
        return None
    for _ in range(2):  # refit, then take the inliers of the refit plane
        normal, centroid = fit_plane_least_squares(points[best_mask])
        best_mask = np.abs((points - centroid) @ normal) < threshold
    return normal, points[best_mask].mean(axis=0), best_mask


def camera_up(cameras: Cameras) -> np.ndarray:
    """(3,) unit mean up vector of the cameras: −y of OpenCV c2w, averaged."""
    up = -cameras.c2w[:, :3, 1].mean(axis=0)
    norm = np.linalg.norm(up)
    if norm < 1e-6:
        raise FignetError(
            "the cameras' up vectors cancel out; gravity cannot come from them (use `gravity=plane`)"
        )
    return up / norm


def looked_at_point(cameras: Cameras) -> np.ndarray:
    """(3,) the point nearest (least squares) to all optical axes: what the cameras look at."""
    directions = cameras.c2w[:, :3, 2]
    projectors = np.eye(3) - directions[:, :, None] * directions[:, None, :]
    matrix = projectors.sum(axis=0)
    if np.linalg.cond(matrix) > 1e8:  # parallel axes meet nowhere
        return cameras.centres.mean(axis=0) + directions.mean(axis=0)
    return np.linalg.solve(matrix, np.einsum("nij,nj->i", projectors, cameras.centres))


def scene_size(points, cameras: Cameras | None = None) -> float:
    """Robust size of the scene: the diagonal of the points' 5–95% box (or of the cameras')."""
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) < 10 and cameras is not None:
        points = np.concatenate([points, cameras.centres])
    low, high = np.percentile(points, [5, 95], axis=0)
    return float(np.linalg.norm(high - low)) or 1.0


# ----------------------------------------------------------------------------- alignment


def support_plane(cameras: Cameras, settings: AlignmentSettings):
    """RANSAC support plane of the sparse points: (up normal, point on it, inlier count) or None."""
    points = cameras.points
    if len(points) < 20:
        return None
    up = camera_up(cameras)
    cos_max = np.cos(np.deg2rad(MAX_PLANE_TILT_DEG))
    threshold = settings.plane_threshold * scene_size(points, cameras)
    found = fit_plane_ransac(
        points, threshold, settings.ransac_iterations, settings.seed, allowed=lambda n: abs(n @ up) >= cos_max
    )
    if found is None:
        return None
    normal, centroid, mask = found
    if mask.sum() < MIN_PLANE_INLIER_FRACTION * len(points):
        return None
    # Toward the cameras: most camera centres lie on the positive side.
    if np.median((cameras.centres - centroid) @ normal) < 0:
        normal = -normal
    if np.degrees(np.arccos(np.clip(normal @ up, -1, 1))) > MAX_PLANE_TILT_DEG:
        return None  # the cameras look up at it: not a support plane
    return normal, centroid, int(mask.sum())


def densest_band(heights, width: float) -> tuple[float, int]:
    """(median height, count) of the window [h, h + width] holding the most of `heights` (n,)."""
    ordered = np.sort(heights)
    counts = np.searchsorted(ordered, ordered + width) - np.arange(len(ordered))
    start = int(np.argmax(counts))
    return float(np.median(ordered[start : start + counts[start]])), int(counts[start])


def support_height_along(up, cameras: Cameras, settings: AlignmentSettings) -> np.ndarray:
    """A point on the support plane for a given `up`: the densest band of point heights below
    the cameras (or the lowest camera when there are no points)."""
    heights = cameras.points @ up if len(cameras.points) else np.zeros(0)
    heights = heights[heights < (cameras.centres @ up).min()]
    if len(heights) < 10:
        return looked_at_point(cameras)
    band = settings.plane_threshold * scene_size(cameras.points, cameras)
    height, _ = densest_band(heights, band)
    inliers = np.abs(cameras.points @ up - height) < band
    centroid = cameras.points[inliers].mean(axis=0)
    return centroid + (height - centroid @ up) * up


def gravity(cameras: Cameras, settings: AlignmentSettings):
    """(up, point on the support plane, source, plane inliers) for the chosen gravity source."""
    if settings.gravity in ("plane", "auto"):
        plane = support_plane(cameras, settings)
        if plane is not None:
            return plane[0], plane[1], "plane", plane[2]
        if settings.gravity == "plane":
            raise FignetError(
                f"no support plane found in the {len(cameras.points)} sparse points (a plane within "
                f"{MAX_PLANE_TILT_DEG:.0f}° of the cameras' up holding {MIN_PLANE_INLIER_FRACTION:.0%} of them); "
                "use `gravity=cameras`"
            )
        log.warning("no support plane in the sparse points; up is the cameras' mean up vector")
    up = camera_up(cameras)
    return up, support_height_along(up, cameras, settings), "cameras", 0


def scale_factor(cameras: Cameras, rotation, origin, settings: AlignmentSettings) -> tuple[float, str]:
    """Metres per unit of the levelled frame, from the user's measurement (or the default)."""
    levelled = (cameras.centres - origin) @ rotation.T
    if settings.baseline is not None:
        name_a, name_b, metres = settings.baseline
        index_a, index_b = cameras.index_of(str(name_a)), cameras.index_of(str(name_b))
        distance = float(np.linalg.norm(levelled[index_a] - levelled[index_b]))
        if distance < 1e-9:
            raise FignetError(
                f"cameras {name_a} and {name_b} are at the same place; choose two that are apart"
            )
        return float(metres) / distance, f"distance {name_a}–{name_b} = {metres} m"
    height = settings.camera_height if settings.camera_height is not None else DEFAULT_CAMERA_HEIGHT
    mean_height = float(levelled[:, 2].mean())
    if mean_height <= 1e-9:
        raise FignetError(
            "the cameras are not above the support plane on average; use `gravity=cameras` or `baseline`"
        )
    source = "mean camera height" + (" (default)" if settings.camera_height is None else "")
    return height / mean_height, f"{source} = {height} m"


def find_alignment(cameras: Cameras, settings: AlignmentSettings = AlignmentSettings()) -> Alignment:
    """The similarity that puts `cameras` into metres, z up, support plane at z = 0."""
    if settings.gravity == "none":
        return Alignment(1.0, np.eye(3), np.zeros(3), "none", "none (kept)")
    if settings.support_plane not in SUPPORT_CHOICES:
        raise FignetError(
            f"support plane {settings.support_plane!r} is not one of {', '.join(SUPPORT_CHOICES)}"
        )
    up, on_plane, source, inliers = gravity(cameras, settings)
    candidates, chosen = [], None
    if source == "plane":
        refined = _compact_plane(cameras, np.asarray(cameras.points, float), up, on_plane, settings)
        if refined is not None:  # the RANSAC plane, refit to its own compact patch
            up, on_plane, inliers = refined["normal"], refined["point"], refined["count"]
        candidates = parallel_planes(cameras, up, on_plane, settings)
        if candidates:
            chosen = choose_plane(candidates, settings.support_plane, looked_at_point(cameras))
            up, on_plane, inliers = chosen["normal"], chosen["point"], chosen["count"]
    rotation = rotation_between(up, [0.0, 0.0, 1.0])
    scale, scale_source = scale_factor(cameras, rotation, on_plane, settings)
    planes = tuple(
        {
            "height": 0.0 if plane is chosen else scale * float((plane["point"] - on_plane) @ up),
            "share": plane["count"] / len(cameras.points),
            "extent": [scale * e for e in plane["extent"]],
            "chosen": plane is chosen,
        }
        for plane in candidates
    )
    return Alignment(scale, rotation, on_plane, source, scale_source, inliers, planes)


def parallel_planes(cameras: Cameras, up, on_plane, settings: AlignmentSettings) -> list:
    """Horizontal planes below the cameras, roughly parallel to the one through `on_plane` with
    normal `up`: the densest height bands of the points (band width the RANSAC threshold), taken
    out one by one while one holds at least MIN_CANDIDATE_FRACTION of the points. Within a band
    only its largest spatially connected cluster counts (_compact_plane: wall points at a
    table's height are not the table); it must fill its box (not a ring of wall points) and is
    refit with a tight threshold. Each: normal, point (on the refit plane), count, extent
    (middle 90 % across the plane, unscaled), offset (along `up` from `on_plane`); highest first."""
    points = np.asarray(cameras.points, float)
    heights = (points - on_plane) @ up
    below = heights < ((cameras.centres - on_plane) @ up).min()
    band = settings.plane_threshold * scene_size(points, cameras)
    planes, left = [], below.copy()
    while left.sum() >= max(3, MIN_CANDIDATE_FRACTION * len(points)):
        offset, count = densest_band(heights[left], 2 * band)
        if count < MIN_CANDIDATE_FRACTION * len(points):
            break
        members = left & (np.abs(heights - offset) < band)
        plane = _compact_plane(cameras, points[members], up, on_plane + offset * up, settings)
        if plane is not None and plane["count"] >= MIN_CANDIDATE_FRACTION * len(points):
            plane["offset"] = float((plane["point"] - on_plane) @ up)
            planes.append(plane)
        left &= ~(np.abs(heights - offset) < 2 * band)
    return sorted(planes, key=lambda plane: -plane["offset"])


def _compact_plane(cameras: Cameras, points, up, near, settings: AlignmentSettings) -> dict | None:
    """The plane of the largest spatially connected cluster of `points` (n, 3), which lie near
    the plane through `near` with normal `up`: {normal (toward `up`), point, count, extent,
    fill}, extent along the cluster's own axes (_own_axes), or None when the cluster does not fill its box (a ring: walls, a rim) or is too small.

    The cluster: points linked when closer across the plane than CLUSTER_LINK times the median
    distance to their 4th neighbour. The refit: RANSAC within PLANE_TILT_REFINE_DEG of `up`,
    with inliers within PLANE_REFINE_TOLERANCE of the points' median distance to the cameras
    (what structure from motion's noise grows with), then least squares on the inliers."""
    points = np.asarray(points, float)
    if len(points) < 10:
        return None
    across = np.linalg.svd(np.eye(3) - np.outer(up, up))[0][:, :2]  # two axes in the plane
    cluster = points[_largest_cluster(points @ across)]
    if len(cluster) < 10:
        return None
    flat = cluster @ across
    flat = _own_axes(flat)
    low, high = np.percentile(flat, [5, 95], axis=0)
    fill = _area_filled(flat, low, high)
    if fill < MIN_PLANE_FILL:  # not a ring of wall points at one height
        return None
    distance = float(np.median(np.linalg.norm(cluster - cameras.centres.mean(axis=0), axis=1)))
    tight = max(PLANE_REFINE_TOLERANCE * distance, 1e-9)
    cos_max = np.cos(np.deg2rad(PLANE_TILT_REFINE_DEG))
    found = fit_plane_ransac(
        cluster, tight, settings.ransac_iterations, settings.seed, allowed=lambda n: abs(n @ up) >= cos_max
    )
    if found is None:
        normal, point, count = np.asarray(up, float), near + ((cluster - near) @ up).mean() * up, len(cluster)
    else:
        normal, point, mask = found
        normal, count = (normal if normal @ up > 0 else -normal), int(mask.sum())
    return {"normal": normal, "point": point, "count": count, "extent": (high - low).tolist(), "fill": fill}


def _own_axes(flat) -> np.ndarray:
    """2-d points (n, 2) turned onto the axes (every 5°) of their smallest 5–95 % box, longest
    first: a table's extent is its length and width, whichever way SfM turned it."""
    best = None
    for angle in np.deg2rad(np.arange(0, 90, 5)):
        turned = flat @ np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        low, high = np.percentile(turned, [5, 95], axis=0)
        if best is None or np.prod(high - low) < best[0]:
            best = (np.prod(high - low), turned[:, np.argsort(low - high)])
    return best[1]


def _largest_cluster(flat) -> np.ndarray:
    """Mask of the largest connected cluster of 2-d points (n, 2), linking points closer than
    CLUSTER_LINK times the median distance to their 4th nearest neighbour."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    tree = cKDTree(flat)
    k = min(5, len(flat))
    spacing = float(np.median(tree.query(flat, k=k)[0][:, -1]))
    span = float(np.linalg.norm(np.ptp(flat, axis=0))) or 1.0
    pairs = tree.query_pairs(max(CLUSTER_LINK * spacing, 1e-6 * span), output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(flat), len(flat)))
    _, labels = connected_components(graph, directed=False)
    return labels == np.argmax(np.bincount(labels))


def _area_filled(flat, low, high, cells: int = 16) -> float:
    """Share of a cells × cells grid over [low, high] that holds a point: near 1 for a surface,
    small for the ring that walls or a container's rim leave at one height."""
    inside = np.all((flat >= low) & (flat <= high), axis=1)
    index = np.minimum(((flat[inside] - low) / np.maximum(high - low, 1e-12) * cells).astype(int), cells - 1)
    return len({tuple(i) for i in index}) / cells**2


def choose_plane(candidates: list, choice: str, looked_at=None) -> dict:
    """The candidate `choice` names: 'auto' (the highest plane under the point the cameras
    look at, else the largest), 'largest' (most points), 'highest' or 'lowest'.

    Under: the looked-at point lies within the plane's extent across it (with a margin of a
    tenth of it) and no lower than LOOKED_AT_BELOW of the plane's distance to that point below it."""
    if choice not in SUPPORT_CHOICES:
        raise FignetError(f"support plane {choice!r} is not one of {', '.join(SUPPORT_CHOICES)}")
    if choice == "highest":
        return candidates[0]
    if choice == "lowest":
        return candidates[-1]
    largest = max(candidates, key=lambda plane: plane["count"])
    if choice == "largest" or looked_at is None:
        return largest
    under = [plane for plane in candidates if _is_under(plane, np.asarray(looked_at, float))]
    return under[0] if under else largest


def _is_under(plane: dict, target) -> bool:
    """Whether `target` (3,) stands on `plane`: above it (or at most 2 cm per metre of the
    plane's extent below it) and inside its 5–95 % extent widened by a tenth."""
    normal, point = plane["normal"], plane["point"]
    size = float(np.linalg.norm(plane["extent"]))
    if (target - point) @ normal < -LOOKED_AT_BELOW * size:
        return False
    across = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    return bool(np.all(np.abs((target - point) @ across) <= 0.6 * np.max(plane["extent"]) + 0.1 * size))


def apply_similarity(cameras: Cameras, scale: float, rotation, translation) -> Cameras:
    """Cameras and points moved by x' = scale · rotation · x + translation (rotations stay rotations)."""
    c2w = cameras.c2w.copy()
    c2w[:, :3, :3] = rotation @ cameras.c2w[:, :3, :3]
    c2w[:, :3, 3] = scale * cameras.centres @ rotation.T + translation
    points = scale * np.asarray(cameras.points, float).reshape(-1, 3) @ rotation.T + translation
    return dataclasses.replace(cameras, c2w=c2w, points=points)


def align(cameras: Cameras, settings: AlignmentSettings = AlignmentSettings()) -> tuple[Cameras, Alignment]:
    """`cameras` in metres with z up and the support plane at z = 0, and the alignment used."""
    alignment = find_alignment(cameras, settings)
    matrix = alignment.matrix()
    aligned = apply_similarity(cameras, alignment.scale, alignment.rotation, matrix[:3, 3])
    return aligned, alignment
