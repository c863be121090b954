"""Tiny exact test data for capture-poses: textured rectangles ray-cast by numpy.

A table top (z = 0) with two boxes on it, each face covered by its own random multi-scale
noise texture, seen by pinhole cameras on a ring above it. The cameras are known exactly
(metres, z up, OpenCV c2w), so structure from motion can be checked against them.
"""

from pathlib import Path

import numpy as np

from fignetctl.core.cameras import Cameras
from fignetctl.core.pinhole import look_at


def ring_cameras(count, radius=0.8, height=0.5, jitter=0.0, arc_deg=360.0, seed=0) -> np.ndarray:
    """(count, 4, 4) cameras on a ring around the origin, looking at the table's centre."""
    rng = np.random.default_rng(seed)
    angles = np.deg2rad(np.arange(count) * arc_deg / count)
    c2w = []
    for angle in angles:
        eye = np.array([radius * np.cos(angle), radius * np.sin(angle), height]) + rng.normal(0, jitter, 3)
        target = np.array([0.0, 0.0, 0.05]) + rng.normal(0, jitter, 3)
        c2w.append(look_at(eye, target))
    return np.array(c2w)


def _noise_texture(rng, size=256) -> np.ndarray:
    """(size, size, 3) float in [0, 1]: random noise summed over several scales."""
    import cv2

    texture = np.zeros((size, size, 3))
    for cells in (4, 8, 16, 32, 64):
        coarse = rng.random((cells, cells, 3))
        texture += cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
    texture -= texture.min()
    return texture / texture.max()


def _box_faces(centre, size):
    """Five visible faces (no bottom) of an axis-aligned box: (origin, u edge, v edge)."""
    cx, cy, cz = centre
    sx, sy, sz = size
    low = np.array([cx - sx / 2, cy - sy / 2, cz])
    ex, ey, ez = np.array([sx, 0, 0]), np.array([0, sy, 0]), np.array([0, 0, sz])
    return [
        (low + ez, ex, ey),  # top
        (low, ex, ez),  # y = low
        (low + ey, ex, ez),  # y = high
        (low, ey, ez),  # x = low
        (low + ex, ey, ez),  # x = high
    ]


def scene_rectangles(table_size=1.0):
    """The table top and two boxes as rectangles (origin, u edge, v edge)."""
    half = table_size / 2
    table = (np.array([-half, -half, 0.0]), np.array([table_size, 0, 0]), np.array([0, table_size, 0]))
    return [
        table,
        *_box_faces((0.1, 0.05, 0.0), (0.2, 0.15, 0.12)),
        *_box_faces((-0.2, -0.15, 0.0), (0.12, 0.12, 0.2)),
    ]


def render(c2w, K, width, height, rectangles, textures, background=0.3) -> np.ndarray:
    """(height, width, 3) uint8 RGB image of the textured rectangles seen by one camera."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pixels = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3)
    directions = pixels @ np.linalg.inv(K).T @ c2w[:3, :3].T
    origin = c2w[:3, 3]
    depth = np.full(len(directions), np.inf)
    colour = np.full((len(directions), 3), background)
    for (corner, edge_u, edge_v), texture in zip(rectangles, textures):
        normal = np.cross(edge_u, edge_v)
        denominator = directions @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((corner - origin) @ normal) / denominator
        hit = origin + t[:, None] * directions
        a = (hit - corner) @ edge_u / (edge_u @ edge_u)
        b = (hit - corner) @ edge_v / (edge_v @ edge_v)
        visible = (t > 1e-6) & (t < depth) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        size = texture.shape[0]
        ia = np.clip((a[visible] * (size - 1)).astype(int), 0, size - 1)
        ib = np.clip((b[visible] * (size - 1)).astype(int), 0, size - 1)
        colour[visible] = texture[ib, ia]
        depth[visible] = t[visible]
    return (colour.reshape(height, width, 3) * 255).round().astype(np.uint8)


def render_views(out_dir, count=8, width=320, height=240, focal=280.0, seed=0, **ring) -> Cameras:
    """Render `count` views as PNGs into `out_dir`; return the exact cameras (with no points)."""
    import cv2

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    rectangles = scene_rectangles()
    textures = [_noise_texture(rng, 512 if index == 0 else 128) for index in range(len(rectangles))]
    K = np.array([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1.0]])
    c2w = ring_cameras(count, seed=seed, **ring)
    names = []
    for index, pose in enumerate(c2w):
        name = f"view_{index:03d}.png"
        image = render(pose, K, width, height, rectangles, textures)
        cv2.imwrite(str(out_dir / name), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        names.append(name)
    return Cameras(np.array(names), np.tile(K, (count, 1, 1)), c2w, width, height)


def distort_image(image, K, k1: float) -> np.ndarray:
    """The pinhole `image` (intrinsics K) as a lens with radial distortion k1 would record it
    (OpenCV's model, k2 = p1 = p2 = 0): each pixel centre of the result is undistorted and the
    pinhole image sampled there. k1 > 0 (pincushion) samples only inside the image."""
    import cv2

    height, width = image.shape[:2]
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    centres = np.stack([u + 0.5, v + 0.5], -1).reshape(-1, 1, 2)
    source = cv2.undistortPoints(centres, K, np.array([k1, 0.0, 0.0, 0.0]), P=K).reshape(height, width, 2)
    source = (source - 0.5).astype(np.float32)  # continuous coordinates -> pixel indices
    return cv2.remap(image, source[..., 0], source[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def resample(image, K, K_new, width: int, height: int) -> np.ndarray:
    """A pinhole `image` (K) as seen by a pinhole camera K_new at the same pose."""
    import cv2

    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    x = (u + 0.5 - K_new[0, 2]) / K_new[0, 0]
    y = (v + 0.5 - K_new[1, 2]) / K_new[1, 1]
    map_u = (K[0, 0] * x + K[0, 2] - 0.5).astype(np.float32)
    map_v = (K[1, 1] * y + K[1, 2] - 0.5).astype(np.float32)
    return cv2.remap(image, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
