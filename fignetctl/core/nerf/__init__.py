"""A torch radiance field (dense density grid + colour features, DVGO-like) for fit-nerf.

model = load_nerf("nerf.pt")
rgb, depth, opacity, median_depth = model.render(cameras, index)   # any pinhole camera
out = model.render_rays(origins, directions, warp=bend)   # ray bending for rerender
sigma = model.density(points)                             # for extract-mesh
"""

from fignetctl.core.nerf.config import PRESETS, NerfConfig, preset_config
from fignetctl.core.nerf.io import FORMAT, FORMAT_VERSION, load_nerf, read_nerf_payload, save_nerf
from fignetctl.core.nerf.model import NerfModel, Rendering

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "PRESETS",
    "NerfConfig",
    "NerfModel",
    "Rendering",
    "load_nerf",
    "preset_config",
    "read_nerf_payload",
    "save_nerf",
]
