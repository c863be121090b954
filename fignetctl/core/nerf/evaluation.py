"""Image and depth metrics of a field on held-out views."""

from __future__ import annotations

import numpy as np


def psnr(mse: float) -> float:
    """Peak signal-to-noise ratio (dB) of images in [0, 1] from their mean squared error."""
    return float(-10.0 * np.log10(max(mse, 1e-12)))


def evaluate_views(model, views, indices, depth_truth=None, max_depth_scale=None, region=None):
    """Render the views at `indices`; PSNR per view and, with `depth_truth` (N, H, W) z-depth at
    the views' size, the median absolute depth error over pixels where both are valid. With a
    `region` box (2, 3), also the region PSNR: over the pixels whose rays pass through the box
    (what lies in it and what is seen through it), per view, and their share of the pixels.

    returns {"psnr": mean over views (of per-view PSNR), "per_view": [...], "depth_median_abs_error": ...,
    "region_psnr": mean over the views that see the region}
    """
    from fignetctl.core.nerf.region import region_pixels

    per_view, errors, renderings = [], [], []
    for i in indices:
        rendering = model.render(views.cameras, int(i))
        renderings.append(rendering)
        mse = float(np.mean((rendering.rgb - views.images[i]) ** 2))
        entry = {"view": int(i), "psnr": psnr(mse)}
        if region is not None:
            inside = region_pixels(views.cameras, int(i), region)
            entry["region_pixels"] = float(inside.mean())
            if inside.any():
                entry["region_psnr"] = psnr(
                    float(np.mean((rendering.rgb[inside] - views.images[i][inside]) ** 2))
                )
        if depth_truth is not None:
            truth = depth_truth[i]
            valid = np.isfinite(truth) & (truth > 0) & (rendering.opacity > 0.5)
            if max_depth_scale is not None:
                valid &= truth < max_depth_scale
            if valid.any():
                error = np.abs(rendering.depth[valid] - truth[valid])
                errors.append(error)
                entry["depth_median_abs_error"] = float(np.median(error))
        per_view.append(entry)
    result = {
        "psnr": float(np.mean([v["psnr"] for v in per_view])) if per_view else float("nan"),
        "per_view": per_view,
    }
    region_values = [v["region_psnr"] for v in per_view if "region_psnr" in v]
    if region is not None:
        result["region_psnr"] = float(np.mean(region_values)) if region_values else float("nan")
    if errors:
        result["depth_median_abs_error"] = float(np.median(np.concatenate(errors)))
    return result, renderings
