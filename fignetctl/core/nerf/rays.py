"""Ray–box intersection and the scene box of posed cameras.

The rays themselves come from `core.pinhole.pixel_rays` (pixel centres at +0.5, camera-frame z
of each direction 1), so the renderer's ray parameters are z-depths and a rendered depth image
unprojects with `pinhole.unproject` (DESIGN.md, perception).
"""

from __future__ import annotations

import numpy as np
import torch

from fignetctl.errors import FignetError


def ray_box_intersection(origins, directions, low, high):
    """Entry and exit ray parameters of an axis-aligned box (slab method).

    origins, directions : (R, 3) tensors; low, high : (3,) tensors
    returns near (R,), far (R,): far <= near where the ray misses; near clamped to >= 0
    """
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t_low = (low - origins) / safe
    t_high = (high - origins) / safe
    near = torch.minimum(t_low, t_high).amax(dim=-1).clamp(min=0.0)
    far = torch.maximum(t_low, t_high).amin(dim=-1)
    return near, far


def look_at_point(c2w) -> np.ndarray:
    """Least-squares point closest to every camera's optical axis.

    c2w : (N, 4, 4) OpenCV
    """
    centres, axes = c2w[:, :3, 3], c2w[:, :3, 2]
    projectors = np.eye(3) - axes[:, :, None] * axes[:, None, :]
    lhs, rhs = projectors.sum(0), np.einsum("nij,nj->i", projectors, centres)
    if np.linalg.cond(lhs) > 1e8:  # parallel axes: a point in front of the cameras
        return centres.mean(0) + axes.mean(0) * np.linalg.norm(centres - centres.mean(0), axis=1).mean()
    return np.linalg.solve(lhs, rhs)


def camera_reach(c2w) -> float:
    """The cameras' median distance to the point they look at (look_at_point)."""
    c2w = np.asarray(c2w, np.float64)
    return float(np.median(np.linalg.norm(c2w[:, :3, 3] - look_at_point(c2w), axis=1)))


def scene_bounds(points, c2w, margin: float = 0.1):
    """Axis-aligned scene box (2, 3): from the sparse points, else from the cameras.

    With 20 or more points: their 1st-99th percentile box, limited along axes where the cameras
    surround the points to the cameras' range grown by their median distance to the point they
    look at, grown on each side by `margin` times its longest
    side, each side at least 5 % of the longest. With fewer: a cube around the point the cameras
    look at, half the median camera distance to it in half-size.
    points : (M, 3); c2w : (N, 4, 4)
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    c2w = np.asarray(c2w, np.float64)
    if len(points) >= 20:
        low, high = np.percentile(points, 1, axis=0), np.percentile(points, 99, axis=0)
        # Along an axis where the cameras surround the scene (their range holds the points'
        # median), the region of interest ends at the cameras: a floor seen to the horizon
        # would otherwise stretch the box and coarsen the grid.
        centres = c2w[:, :3, 3]
        median = np.median(points, axis=0)
        # ... the cameras' range grown by their median distance to what they look at, so that
        # walls enclosing an orbit stay inside (they fill the top of every view).
        reach = camera_reach(c2w)
        surrounded = (centres.min(0) - reach < median) & (median < centres.max(0) + reach)
        low = np.where(surrounded, np.maximum(low, centres.min(0) - reach), low)
        high = np.where(surrounded, np.minimum(high, centres.max(0) + reach), high)
        size = np.maximum(high - low, 0.05 * (high - low).max())
        centre = 0.5 * (low + high)
        half = 0.5 * size + margin * size.max()
    else:
        centre = look_at_point(c2w)
        distance = camera_reach(c2w)
        half = np.full(3, 0.5 * distance)
    bounds = np.stack([centre - half, centre + half])
    if not np.isfinite(bounds).all() or (bounds[1] - bounds[0]).max() <= 0:
        raise FignetError("cannot find the scene's extent from the sparse points and cameras")
    return bounds
