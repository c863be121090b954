"""Pinhole cameras: the one place for projection, unprojection, pixel rays, look-at and orbits.

Axes are OpenCV's (x right, y down, z forward) and poses are camera-to-world (c2w, 4 × 4).

**Pixel convention** (docs/formats.md). Image coordinates are continuous, the image covering
[0, width] × [0, height]; pixel (u, v) (column, row, integers from the top left) covers
[u, u + 1) × [v, v + 1) and its centre is the image point (u + 0.5, v + 0.5), as in COLMAP and
nerfstudio. So

- a world point projects to image point (x/z, y/z) of K · (camera-frame point) and lies in pixel
  floor of that;
- pixel (u, v)'s ray has direction R · K⁻¹ · (u + 0.5, v + 0.5, 1) (camera-frame z = 1), so a
  ray parameter is a z-depth, and a z-depth image unprojects through the same pixel centres;
- an image resized by (s_x, s_y) has K's first two rows scaled by them, nothing else.

Every producer of cameras (render-views' ground truth, capture-poses through COLMAP,
transforms.json, the orbits of rerender and show) and every consumer (fit-nerf's rays,
extract-mesh's unprojection and masks, rerender) uses these functions.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

PIXEL_CENTRE = 0.5
"""Offset of a pixel's centre from its integer index, in image coordinates."""

_SMALLEST_DEPTH = 1e-9


class Camera(NamedTuple):
    """One pinhole camera: K (3, 3), c2w (4, 4) OpenCV, image width and height in pixels."""

    K: np.ndarray
    c2w: np.ndarray
    width: int
    height: int

    @property
    def eye(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return np.asarray(self.c2w, np.float64)[:3, 3]

    def project(self, points) -> tuple:
        """project(K, c2w, points) of this camera."""
        return project(self.K, self.c2w, points)

    def rays(self) -> tuple:
        """pixel_rays of this camera, flattened: origins (H·W, 3), directions (H·W, 3)."""
        origins, directions = pixel_rays(self.K, self.c2w, self.width, self.height)
        return origins.reshape(-1, 3), directions.reshape(-1, 3)


def project(K, c2w, points) -> tuple:
    """World points (N, 3) -> image points (N, 2) (continuous; pixel centres at +0.5) and
    z-depths (N,). Points at or behind the camera get far-off image points: filter on depth."""
    K, c2w = np.asarray(K, np.float64), np.asarray(c2w, np.float64)
    local = (np.asarray(points, np.float64).reshape(-1, 3) - c2w[:3, 3]) @ c2w[:3, :3]
    depth = local[:, 2]
    image = local @ K.T
    return image[:, :2] / np.maximum(depth, _SMALLEST_DEPTH)[:, None], depth


def pixel_of(image_points) -> np.ndarray:
    """(N, 2) image points -> (N, 2) int64 (u, v) of the pixels they fall in."""
    return np.floor(np.asarray(image_points, np.float64)).astype(np.int64)


def unproject(K, c2w, u, v, depth) -> np.ndarray:
    """World points (P, 3) at z-depths `depth` (P,) on the rays of pixels (u, v) (P,) each."""
    directions = camera_directions(K, np.asarray(u), np.asarray(v))
    local = directions * np.asarray(depth, np.float64)[..., None]
    c2w = np.asarray(c2w, np.float64)
    return local @ c2w[:3, :3].T + c2w[:3, 3]


def camera_directions(K, u, v) -> np.ndarray:
    """Camera-frame directions K⁻¹ · (u + 0.5, v + 0.5, 1) of integer pixels (any equal shapes)."""
    pixels = np.stack(
        [
            np.asarray(u, np.float64) + PIXEL_CENTRE,
            np.asarray(v, np.float64) + PIXEL_CENTRE,
            np.ones(np.shape(u)),
        ],
        axis=-1,
    )
    return pixels @ np.linalg.inv(np.asarray(K, np.float64)).T


def camera_frame_points(depth, K) -> np.ndarray:
    """(H, W) z-depth image -> (H, W, 3) camera-frame points through the pixel centres."""
    height, width = np.shape(depth)
    v, u = np.mgrid[0:height, 0:width]
    return camera_directions(K, u, v) * np.asarray(depth, np.float64)[..., None]


def pixel_rays(K, c2w, width: int, height: int) -> tuple:
    """Rays through every pixel centre: origins (H, W, 3) and directions (H, W, 3) float64, each
    direction with camera-frame z = 1 (ray parameters are z-depths)."""
    v, u = np.mgrid[0:height, 0:width]
    c2w = np.asarray(c2w, np.float64)
    directions = camera_directions(K, u, v) @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], directions.shape).copy()
    return origins, directions


def scale_intrinsics(K, scale_x: float, scale_y: float) -> np.ndarray:
    """K (..., 3, 3) of an image resized by (scale_x, scale_y)."""
    K = np.array(K, np.float64)
    K[..., 0, :] *= scale_x
    K[..., 1, :] *= scale_y
    return K


def intrinsics_from_fov(width: int, height: int, fov_y_deg: float) -> np.ndarray:
    """(3, 3) K with square pixels, the vertical field of view given, centred in the image."""
    focal = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2.0)
    return np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye, target) -> np.ndarray:
    """(4, 4) c2w at `eye` looking at `target`, world z up (image y down); a camera looking
    straight down gets world x as its right."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([1.0, 0.0, 0.0])
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)
    c2w[:3, 3] = eye
    return c2w


def orbit(centre, radius: float, elevation_deg: float, count: int, azimuth_deg: float = 0.0) -> np.ndarray:
    """(count, 4, 4) c2w on a circle around `centre` (one turn from `azimuth_deg`, measured
    around z from +x), at `elevation_deg` above it, each looking at it."""
    centre = np.asarray(centre, np.float64)
    elevation = math.radians(elevation_deg)
    azimuths = math.radians(azimuth_deg) + 2 * math.pi * np.arange(count) / max(count, 1)
    offsets = radius * np.stack(
        [
            np.cos(azimuths) * math.cos(elevation),
            np.sin(azimuths) * math.cos(elevation),
            np.full(count, math.sin(elevation)),
        ],
        axis=1,
    )
    return np.stack([look_at(centre + offset, centre) for offset in offsets]).reshape(count, 4, 4)
