"""Object masks from a point prompt, offline on the CPU: OpenCV GrabCut seeded at the prompt
and constrained by depth (paper: XMem from a point prompt; no model weights here).

For one view: the prompt pixel's depth gives its 3D point p. Pixels whose 3D point lies
farther than `max_size` from p are certain background, and so are pixels on the large planes
around p (RANSAC: the support the object stands on, and pixels behind it; then up to two more,
e.g. a container's walls); pixels connected to the prompt across no depth jump and within
`max_size / 2` of p are probable foreground; a small disk at the prompt is certain foreground. GrabCut decides the rest from colour; the mask is then the connected
component holding the prompt, with holes filled.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fignetctl.core.pinhole import camera_frame_points
from fignetctl.errors import FignetError


@dataclasses.dataclass(frozen=True)
class SegmentationSettings:
    """How a prompt becomes a mask."""

    max_size: float = 0.25
    """Largest object extent (world units): pixels farther than this from the prompt's 3D point are background."""
    depth_jump: float = 0.03
    """Relative depth step between neighbouring pixels that separates surfaces."""
    seed_radius: int = 2
    """Radius (pixels) of the certain-foreground disk at the prompt."""
    iterations: int = 5
    """GrabCut iterations."""
    plane_tolerance: float = 0.02
    """Points within this fraction of max_size of a plane belong to it."""
    min_plane_fraction: float = 0.1
    """A plane must hold this fraction of the points within max_size of the prompt to count as background."""
    min_opacity: float = 0.5
    """A prompt on a pixel whose rendered opacity is below this is on empty space."""
    depth_noise: float = 0.0
    """The depth's expected error (world units), e.g. the NeRF's finest voxel. A coarse field's
    depth scatters about a plane by about a voxel: with `plane_tolerance` RANSAC may then find
    no support, only thin slabs of noise that cut through the object and leave a sliver of a
    mask. When the mask holds less than `min_near_fraction` of the depth-connected pixels near
    the prompt, it is made again with planes `noise_planes` times this thick, and the larger
    of the two is kept."""
    noise_planes: float = 1.5
    """See `depth_noise`."""
    min_near_fraction: float = 0.5
    """See `depth_noise`."""


def check_prompt(u, v, width, height, depth, opacity=None, settings=SegmentationSettings(), where="prompt"):
    """A FignetError in one line if (u, v) is outside the image or on empty space."""
    if not (0 <= u < width and 0 <= v < height):
        raise FignetError(f"{where}: pixel ({u}, {v}) is outside the {width}x{height} image")
    z = float(depth[v, u])
    empty = (
        not np.isfinite(z) or z <= 0 or (opacity is not None and float(opacity[v, u]) < settings.min_opacity)
    )
    if empty:
        raise FignetError(f"{where}: pixel ({u}, {v}) is on empty space (no density along its ray)")


def depth_connected(depth, seed, max_jump):
    """(H, W) bool: pixels reachable from `seed` (v, u) through 4-neighbours whose depths
    differ by less than `max_jump` (relative)."""
    import cv2

    depth = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0, posinf=0.0)
    log_depth = np.log(np.maximum(depth, 1e-9)).astype(np.float32)
    mask = np.zeros((depth.shape[0] + 2, depth.shape[1] + 2), np.uint8)
    flags = 4 | cv2.FLOODFILL_MASK_ONLY | (1 << 8)
    step = float(np.log1p(max_jump))
    cv2.floodFill(log_depth.copy(), mask, (int(seed[1]), int(seed[0])), 0, step, step, flags)
    return mask[1:-1, 1:-1].astype(bool)


def prompt_mask(image, depth, K, u, v, settings=SegmentationSettings()):
    """The object's mask at prompt (u, v).

    image : (H, W, 3) uint8 RGB; depth : (H, W) z-depth; K : (3, 3)
    returns (H, W) bool
    """
    points = camera_frame_points(depth, K)
    distance = np.linalg.norm(points - points[v, u], axis=-1)
    distance[~np.isfinite(distance)] = np.inf
    near = depth_connected(depth, (v, u), settings.depth_jump) & (distance < 0.5 * settings.max_size)
    tolerance = settings.plane_tolerance * settings.max_size
    mask = _prompt_mask(image, points, distance, near, u, v, settings, tolerance)
    noisy = settings.noise_planes * settings.depth_noise
    if noisy > tolerance and mask.sum() < settings.min_near_fraction * near.sum():
        retry = _prompt_mask(image, points, distance, near, u, v, settings, noisy)
        if retry.sum() > mask.sum():
            mask = retry
    return mask


def _prompt_mask(image, points, distance, near, u, v, settings, tolerance):
    """`prompt_mask` with planes of this `tolerance` (world units)."""
    import cv2

    support = plane_pixels(points, distance < settings.max_size, points[v, u], settings, tolerance=tolerance)
    labels = np.full(distance.shape, cv2.GC_PR_BGD, np.uint8)
    labels[near & ~support] = cv2.GC_PR_FGD
    labels[(distance > settings.max_size) | support] = cv2.GC_BGD
    cv2.circle(labels, (int(u), int(v)), int(settings.seed_radius), int(cv2.GC_FGD), -1)
    if (labels == cv2.GC_BGD).all() or not (labels == cv2.GC_BGD).any():
        labels[0, :] = labels[-1, :] = labels[:, 0] = labels[:, -1] = cv2.GC_BGD
    return fill_holes(component_at(grabcut(image, labels, settings.iterations), v, u))


def grabcut(image, labels, iterations):
    """GrabCut from a label image (cv2.GC_* per pixel) -> (H, W) bool foreground.

    image : (H, W, 3) uint8 RGB; labels : (H, W) uint8, refined in place. OpenCV's global
    generator, which GrabCut's k-means draws from, is seeded first: the same inputs give the
    same mask whatever ran before.
    """
    import cv2

    background, foreground = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    bgr = np.ascontiguousarray(np.asarray(image, np.uint8)[..., ::-1])
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, labels, None, background, foreground, iterations, cv2.GC_INIT_WITH_MASK)
    return (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)


def plane_pixels(points, neighbourhood, prompt_point, settings, planes=3, tolerance=None):
    """(H, W) bool: pixels on the large planes around the prompt, found one after another by
    RANSAC among the neighbourhood's 3D points (planes through the prompt's own point are not
    taken, nor planes holding fewer than `settings.min_plane_fraction` of the points). The first
    is the surface the object stands on: the pixels behind it count too. `tolerance` (world
    units; default plane_tolerance × max_size): how near a plane a point must be to be on it."""
    rng = np.random.default_rng(0)
    candidates = points[neighbourhood]
    candidates = candidates[np.isfinite(candidates).all(axis=1)]
    candidates = candidates[rng.choice(len(candidates), min(3000, len(candidates)), replace=False)]
    total = len(candidates)
    tolerance = settings.plane_tolerance * settings.max_size if tolerance is None else tolerance
    result = np.zeros(points.shape[:2], bool)
    for index in range(planes):
        plane = _ransac_plane(candidates, prompt_point, tolerance, rng)
        if plane is None or total < 50 or plane[2] < settings.min_plane_fraction * total:
            break
        normal, offset, _ = plane
        signed = np.nan_to_num(points @ normal + offset, nan=np.inf)
        result |= (signed < tolerance) if index == 0 else (np.abs(signed) < tolerance)
        candidates = candidates[np.abs(candidates @ normal + offset) >= tolerance]
    return result


def _ransac_plane(points, prompt_point, tolerance, rng, trials=200):
    """(normal (3,) facing the prompt, offset, inlier count) of the plane with most inliers
    that does not pass through the prompt's point; None for too few points."""
    if len(points) < 50:
        return None
    triples = points[rng.integers(len(points), size=(trials, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    length = np.linalg.norm(normals, axis=1)
    good = length > 1e-12
    normals, triples = normals[good] / length[good, None], triples[good]
    if len(normals) == 0:
        return None
    offsets = -np.einsum("ij,ij->i", normals, triples[:, 0])
    prompt_distance = normals @ prompt_point + offsets
    inliers = (np.abs(points @ normals.T + offsets) < tolerance).sum(0)
    inliers[np.abs(prompt_distance) < 3 * tolerance] = 0
    best = int(np.argmax(inliers))
    side = 1.0 if prompt_distance[best] >= 0 else -1.0
    return normals[best] * side, offsets[best] * side, int(inliers[best])


def component_at(mask, v, u):
    """The 8-connected component of `mask` holding pixel (v, u) (empty if it is not set)."""
    import cv2

    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if not mask[v, u]:
        return np.zeros_like(mask, bool)
    return labels == labels[v, u]


def fill_holes(mask, max_fraction=None):
    """Fill the holes of a binary mask (background not connected to the image border); with
    `max_fraction`, only holes no larger than that fraction of the mask's area (specks, not
    the opening of a mug's handle)."""
    import cv2

    padded = np.pad(mask.astype(np.uint8), 1)
    flood = padded.copy()
    cv2.floodFill(flood, np.zeros((flood.shape[0] + 2, flood.shape[1] + 2), np.uint8), (0, 0), 1)
    holes = (1 - flood).astype(np.uint8)
    if max_fraction is not None:
        _, labels, stats, _ = cv2.connectedComponentsWithStats(holes, connectivity=4)
        small = stats[:, cv2.CC_STAT_AREA] <= max_fraction * padded.sum()
        small[0] = False  # label 0: everything that is not a hole
        holes = small[labels].astype(np.uint8)
    return (padded | holes).astype(bool)[1:-1, 1:-1]


def iou(a, b):
    """Intersection over union of two boolean masks (1 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = (a | b).sum()
    return 1.0 if union == 0 else float((a & b).sum() / union)
