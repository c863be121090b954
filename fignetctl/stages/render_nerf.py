"""render-nerf: colour and z-depth images of cameras (cameras.npz) from a fitted nerf.pt."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.errors import SettingError
from fignetctl.stages import check, device_setting, resolve_device, setting

MAX_RENDER_SIDE = 4096  # pixels: as render-views' largest image


@dataclasses.dataclass(frozen=True)
class Settings:
    views: str | None = setting(None, "Comma-separated view indices (default: the held-out views, else all).")
    scale: float | None = setting(
        None, "Image scale against cameras.npz.  [default: the trained size]", low=0, low_open=True
    )
    device: str = device_setting()


def run(nerf, cameras, output, settings: Settings = Settings()) -> dict:
    """Render colour and depth of the views `settings.views` of `cameras` (cameras.npz) from the
    field `nerf` (nerf.pt) into the folder `output`: <name>.png, <name>_depth.png (colour-mapped)
    and <name>_depth.npy (float32 z-depth, 0 where nothing is hit). Returns the summary (output,
    the view indices and the names written)."""
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.nerf.visualize import render_views_to_folder

    check(settings)
    scale = settings.scale
    camera_set = read_cameras(cameras)
    if scale is not None and max(camera_set.width, camera_set.height) * scale > MAX_RENDER_SIDE:
        raise SettingError(
            f"--scale: {scale:g} x {camera_set.width}x{camera_set.height} is over "
            f"{MAX_RENDER_SIDE} pixels on a side; lower it"
        )
    model = load_nerf(nerf, device=resolve_device(settings.device))
    indices = _parse_views(settings.views, len(camera_set), model)
    written = render_views_to_folder(model, camera_set, indices, Path(output), scale)
    return {"output": str(output), "views": indices, "written": written}


def _parse_views(text, count, model):
    """--views as indices into the cameras; by default the held-out views, else all."""
    if text is None:
        held = model.inputs.get("held_out_views") or []
        return [i for i in held if i < count] or list(range(count))
    try:
        indices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise SettingError(f"--views: {text!r} is not a comma-separated list of integers") from None
    bad = [i for i in indices if not 0 <= i < count]
    if bad or not indices:
        raise SettingError(f"--views: view {bad[0] if bad else text!r} is not in 0..{count - 1}")
    return indices
