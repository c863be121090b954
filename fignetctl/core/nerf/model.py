"""NerfModel: field + occupancy + sampler + renderer, the object a nerf.pt loads into."""

from __future__ import annotations

import typing

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from fignetctl.core.nerf.config import NerfConfig
from fignetctl.core.nerf.field import GridField, OccupancyGrid
from fignetctl.core.nerf.renderer import (
    RegionSteps,
    distortion,
    median_depth,
    per_sample,
    render_samples,
    sample_along_rays,
)
from fignetctl.core.pinhole import pixel_rays
from fignetctl.errors import FignetError

BACKGROUNDS = {
    "white": (1.0, 1.0, 1.0),
    "black": (0.0, 0.0, 0.0),
    "learned": (0.5, 0.5, 0.5),
    "environment": (0.5, 0.5, 0.5),
}
LEARNED_BACKGROUNDS = ("learned", "environment")


class Rendering(typing.NamedTuple):
    """A rendered image: rgb (H, W, 3) float32 in [0, 1], depth (H, W) z-depth Σ w t / Σ w (0
    where nothing is hit), opacity (H, W) accumulated alpha, median_depth (H, W) z-depth where
    the ray has lost half its light (`renderer.median_depth`: on the surface even with haze in
    front of it, which pulls `depth` towards the camera)."""

    rgb: np.ndarray
    depth: np.ndarray
    opacity: np.ndarray
    median_depth: np.ndarray


class NerfModel(nn.Module):
    """A radiance field on a scene box, with rendering for any pinhole camera; with a `region`
    (2, 3) inside the box, fine grids there and coarse ones elsewhere (GridField)."""

    def __init__(self, config: NerfConfig, bounds, density_resolution=None, region=None):
        super().__init__()
        if config.background not in BACKGROUNDS:
            raise FignetError(f"background {config.background!r} is not one of {sorted(BACKGROUNDS)}")
        self.config = config
        self.field = GridField(bounds, config, density_resolution, region=region)
        self.occupancy = OccupancyGrid(
            bounds,
            self.field.density_grid.shape[2:],
            region,
            self.field.region_density_grid.shape[2:] if region is not None else None,
        )
        logit = torch.logit(torch.tensor(BACKGROUNDS[config.background]).clamp(1e-3, 1 - 1e-3))
        if config.background == "environment":
            rows = max(2, int(config.environment_resolution))
            logit = logit.view(1, 3, 1, 1).expand(1, 3, rows, 2 * rows).contiguous()
        self.background_logit = nn.Parameter(logit, requires_grad=config.background in LEARNED_BACKGROUNDS)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) scene box (low, high) in world units."""
        return self.field.bounds.detach().cpu().numpy().astype(np.float64)

    @property
    def region(self) -> np.ndarray | None:
        """(2, 3) box of the fine grids, or None (one grid over the scene box)."""
        if not self.field.has_region:
            return None
        return self.field.region.detach().cpu().numpy().astype(np.float64)

    @property
    def voxel_size(self) -> float:
        """Edge of the finest density-grid voxel (the region's when there is one), world units."""
        return self.field.finest_voxel_size

    def background(self, directions):
        """RGB behind the scene seen along `directions` (R, 3): (3,), or (R, 3) with an
        environment map (equirectangular in the world frame, z up)."""
        if self.config.background == "environment":
            unit = directions / directions.norm(dim=-1, keepdim=True).clamp(min=1e-12)
            azimuth = torch.atan2(unit[:, 1], unit[:, 0]) / torch.pi
            elevation = torch.asin(unit[:, 2].clamp(-1.0, 1.0)) / (torch.pi / 2)
            where = torch.stack([azimuth, -elevation], dim=-1).view(1, 1, -1, 2)
            logit = F.grid_sample(
                self.background_logit,
                where.to(self.background_logit.dtype),
                padding_mode="border",
                align_corners=True,
            )
            return torch.sigmoid(logit.view(3, -1).t())
        if self.config.background == "learned":
            return torch.sigmoid(self.background_logit)
        return torch.tensor(BACKGROUNDS[self.config.background], device=self.background_logit.device)

    @property
    def step_length(self) -> float:
        """World distance between samples along a ray; with a region a `RegionSteps`: this
        distance outside the region, carrying the region and the finer one inside it."""
        step = self.config.step_ratio * self.field.voxel_size
        if not self.field.has_region:
            return step
        fine = (self.config.region_step_ratio or self.config.step_ratio) * self.field.region_voxel_size
        return RegionSteps(step, self.field.region[0], self.field.region[1], fine)

    def refresh_occupancy(self) -> None:
        """Re-mark empty space from the current densities (at the density grid's resolution)."""
        # alpha_init is defined at each grid's reference step
        steps = [self.config.step_ratio * voxel for voxel in self.field.reference_voxels()]
        self.occupancy.refresh(self.field, steps[0], self.config.occupancy_threshold, steps[-1])

    # -- the API later stages use -------------------------------------------------------------
    def density(self, points):
        """σ (P,) (1 / world unit) at world points (P, 3), numpy or torch (returns the same kind)."""
        as_numpy = isinstance(points, np.ndarray)
        device = self.field.density_grid.device
        tensor = torch.as_tensor(
            np.asarray(points, np.float32) if as_numpy else points, device=device, dtype=torch.float32
        )
        with torch.set_grad_enabled(not as_numpy and torch.is_grad_enabled()):
            sigma = self.field.density(tensor.reshape(-1, 3))
        return sigma.detach().cpu().numpy() if as_numpy else sigma

    def render_rays(
        self,
        origins,
        directions,
        warp=None,
        jitter=None,
        chunk=None,
        skip_empty=True,
        weight_threshold=None,
        transmittance_threshold=0.0,
        with_distortion=False,
        with_median=False,
    ):
        """Volume-render rays (R, 3) + (R, 3) (torch, any direction length).

        warp(points (P,3)) -> points (P,3) (or (points, directions)) is applied to every sample
        point before the field is queried (ray bending). Returns a dict of tensors:
        rgb (R, 3), depth (R,) the expected ray parameter t of the surface (z-depth for
        camera rays from `render`), distance (R,) = depth · |d|, opacity (R,). Samples whose
        compositing weight is below `weight_threshold` (default: the config's) get no colour;
        with `transmittance_threshold` > 0, samples behind which less light is left are dropped.
        `with_distortion`: also distortion (R,), renderer.distortion of each ray's weights, its
        distances in units of the scene box's longest side (what training penalises).
        `with_median`: also median_depth (R,) (`renderer.median_depth`, in ray-parameter units).
        """
        if chunk is not None and len(origins) > chunk:
            parts = [
                self.render_rays(
                    o,
                    d,
                    warp,
                    None if jitter is None else j,
                    None,
                    skip_empty,
                    weight_threshold,
                    transmittance_threshold,
                    with_distortion,
                    with_median,
                )
                for o, d, j in zip(
                    origins.split(chunk),
                    directions.split(chunk),
                    (jitter.split(chunk) if jitter is not None else [None] * len(origins.split(chunk))),
                )
            ]
            return {key: torch.cat([p[key] for p in parts]) for key in parts[0]}
        low, high = self.field.bounds[0], self.field.bounds[1]
        samples = sample_along_rays(
            origins, directions, low, high, self.step_length, jitter, self.config.near
        )
        occupancy = self.occupancy if skip_empty else None
        rgb, depth, opacity, weights = render_samples(
            self.field,
            occupancy,
            samples,
            directions,
            self.background(directions),
            warp,
            self.config.weight_threshold if weight_threshold is None else weight_threshold,
            transmittance_threshold,
        )
        norms = directions.norm(dim=-1)
        out = {"rgb": rgb, "depth": depth, "distance": depth * norms, "opacity": opacity}
        if with_median:
            lengths = per_sample(samples.step) / norms[:, None]  # each step in ray-parameter units
            out["median_depth"] = median_depth(weights, samples.t, lengths, opacity)
        if with_distortion:
            scale = float((high - low).max())
            out["distortion"] = distortion(weights, samples.t * norms[:, None], samples.step, scale)
        return out

    @torch.no_grad()
    def render(self, camera, index: int = 0, warp=None, chunk: int = 16384, pixels=None) -> Rendering:
        """Render one camera: a `Cameras` (with `index`) or a tuple (K, c2w, width, height);
        only the `pixels` set in an (H, W) bool array when given (the others stay 0)."""
        K, c2w, width, height = _camera_tuple(camera, index)
        origins, directions = pixel_rays(K, c2w, width, height)
        chosen = np.ones((height, width), bool) if pixels is None else np.asarray(pixels, bool)
        device = self.field.density_grid.device
        o = torch.as_tensor(origins[chosen], dtype=torch.float32, device=device)
        d = torch.as_tensor(directions[chosen], dtype=torch.float32, device=device)
        out = self.render_rays(o, d, warp=warp, chunk=chunk, with_median=True)

        def as_image(x, *shape):
            image = np.zeros((height, width, *shape), np.float32)
            image[chosen] = x.reshape(-1, *shape).float().cpu().numpy()
            return image

        return Rendering(
            as_image(out["rgb"].clamp(0, 1), 3),
            as_image(out["depth"]),
            as_image(out["opacity"]),
            as_image(out["median_depth"]),
        )


def _camera_tuple(camera, index):
    if isinstance(camera, tuple) and len(camera) == 4:
        K, c2w, width, height = camera
        return np.asarray(K), np.asarray(c2w), int(width), int(height)
    if hasattr(camera, "K") and hasattr(camera, "c2w"):
        return camera.K[index], camera.c2w[index], int(camera.width), int(camera.height)
    raise FignetError("render needs a Cameras or a tuple (K, c2w, width, height)")
