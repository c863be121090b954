"""Pictures of a fitted field: PNG colour and depth, and a rerun log of a fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fignetctl.core.atomic import atomic_path


def colourise_depth(depth, low=None, high=None) -> np.ndarray:
    """(H, W) depth -> (H, W, 3) uint8 RGB (turbo colour map; black where depth <= 0)."""
    import cv2

    valid = depth > 0
    if not valid.any():
        return np.zeros(depth.shape + (3,), np.uint8)
    low = np.percentile(depth[valid], 1) if low is None else low
    high = np.percentile(depth[valid], 99) if high is None else high
    scaled = np.clip((depth - low) / max(high - low, 1e-9), 0, 1)
    rgb = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    return np.where(valid[..., None], rgb, 0).astype(np.uint8)


def write_png(path, rgb) -> None:
    """Write an RGB image (float in [0, 1] or uint8) atomically."""
    import cv2

    image = rgb if rgb.dtype == np.uint8 else (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    with atomic_path(path) as tmp:
        cv2.imwrite(str(tmp), np.ascontiguousarray(image[..., ::-1]))


def render_views_to_folder(model, cameras, indices, folder, scale=None) -> list:
    """<name>.png, <name>_depth.png, <name>_depth.npy (float32 z-depth) per view index."""
    from fignetctl.core.pinhole import scale_intrinsics

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if scale is None:
        scale = float(model.inputs.get("image_scale", 1.0))
    width, height = max(1, round(cameras.width * scale)), max(1, round(cameras.height * scale))
    written = []
    for i in indices:
        K = scale_intrinsics(cameras.K[i], width / cameras.width, height / cameras.height)
        rendering = model.render((K, cameras.c2w[i], width, height))
        stem = Path(str(cameras.image_names[i])).stem
        write_png(folder / f"{stem}.png", rendering.rgb)
        write_png(folder / f"{stem}_depth.png", colourise_depth(rendering.depth))
        with atomic_path(folder / f"{stem}_depth.npy") as tmp, open(tmp, "wb") as f:
            np.save(f, rendering.depth.astype(np.float32))
        written.append(stem)
    return written


def log_fit_to_rerun(path_rrd, trainer, renderings) -> Path:
    """Loss and PSNR per step, and each held-out view rendered beside its image."""
    from fignetctl.core.rerun_log import recording
    from fignetctl.core.viz import log_scalar_series

    path_rrd = Path(path_rrd)
    with recording(path_rrd) as (rr, rec):
        history = trainer.history
        series = {name: [(r["step"], r[key]) for r in history] for name, key in FIT_SCALARS.items()}
        log_scalar_series(rr, rec, "fit-nerf", series)
        log_held_out(rr, rec, trainer, renderings)
    return path_rrd


FIT_SCALARS = {"loss": "loss", "train_psnr": "psnr"}
"""The curves of a fit: entity fit-nerf/<name> <- the key of a step's record."""


def log_fit_step(rr, rec, record) -> None:
    """One step's loss and PSNR (a record of the trainer's history) into `rec`: the curves of
    `log_fit_to_rerun`, for a viewer watching the fit."""
    from fignetctl.core.viz import log_scalar_step

    values = {name: record[key] for name, key in FIT_SCALARS.items()}
    log_scalar_step(rr, rec, "fit-nerf", record["step"], values)


def log_held_out(rr, rec, trainer, renderings) -> None:
    """Each held-out view, rendered, its image and the rendered depth, at the last step."""
    rec.set_time("step", sequence=int(trainer.step))
    for index, rendering in zip(trainer.held_out_views, renderings):
        name = f"fit-nerf/held_out/view_{int(index):03d}"
        rec.log(f"{name}/rendered", rr.Image((np.clip(rendering.rgb, 0, 1) * 255).astype(np.uint8)))
        rec.log(f"{name}/image", rr.Image((trainer.views.images[index] * 255).astype(np.uint8)))
        rec.log(f"{name}/depth", rr.DepthImage(rendering.depth))
