"""Settings of a radiance-field fit: one frozen dataclass, two presets."""

from __future__ import annotations

import dataclasses
import json


@dataclasses.dataclass(frozen=True)
class NerfConfig:
    """How a radiance field is built and trained (written into every nerf.pt)."""

    max_image_side: int = 200
    """Images are downscaled (INTER_AREA, K scaled with them) so the longer side is at most this."""
    holdout_every: int = 8
    """Views 0, k, 2k, ... are held out for evaluation (0: train on every view)."""
    grid_resolution_initial: int = 48
    """Density-grid vertices along the box's longest side at the start (voxels stay cubic)."""
    grid_resolution: int = 128
    """... and at the end; the grid is upsampled (trilinearly) at `upsample_steps`."""
    upsample_steps: tuple = (400, 900)
    """Steps at which the density grid grows, geometrically from initial to final resolution."""
    feature_resolution: int = 64
    """Colour-feature grid vertices along the longest side at the end."""
    feature_resolution_initial: int = 0
    """... and at the start, growing with the density grid at `upsample_steps` (0: fixed at `feature_resolution`)."""
    feature_channels: int = 12
    """Channels of the colour-feature grid; the first three are a diffuse colour."""
    mlp_width: int = 64
    """Hidden width of the colour MLP (features + view direction in degree-2 SH -> RGB residual);
    0: no MLP, colour = sigmoid(first three features) (diffuse only, cheapest)."""
    step_ratio: float = 0.5
    """Distance between samples along a ray, in voxels of the current density grid."""
    alpha_init: float = 1e-3
    """Opacity of one sample step in the untrained grid."""
    occupancy_threshold: float = 2e-3
    """A vertex is empty when a step (at the final resolution) at its density is less opaque than this
    (dilated by one vertex); above `alpha_init`, so space whose density never rose is skipped."""
    occupancy_every: int = 16
    """Steps between refreshes of the occupancy grid."""
    occupancy_warmup: int = 30
    """No empty-space skipping before this step."""
    weight_threshold: float = 1e-4
    """Samples whose compositing weight is below this skip the colour query."""
    transmittance_threshold: float = 0.0
    """In training after `occupancy_warmup`, samples behind which less than this fraction of light
    is left are dropped by a gradient-free density pass (early ray termination; 0: off)."""
    steps: int = 1500
    """Optimiser steps."""
    rays_per_batch: int = 4096
    """Rays per step, drawn from every pixel of every training view."""
    learning_rate_grid: float = 0.1
    learning_rate_mlp: float = 1e-3
    learning_rate_decay: float = 0.1
    """Both rates decay exponentially to this fraction over `steps`."""
    tv_weight: float = 0.0
    """Weight of a total-variation penalty on the density grid (0: off)."""
    distortion_weight: float = 0.0
    """Weight of the distortion loss (Mip-NeRF 360), which gathers each ray's weight onto one
    surface instead of fog spread along it or split between a surface and what lies behind it
    (0: off)."""
    background: str = "learned"
    """Colour behind the scene: 'learned' (one RGB), 'environment' (a learned RGB per direction:
    what lies beyond the scene box, such as a room's walls), 'white' or 'black'; 'auto':
    'environment' for a capture in a room, else 'learned' (`for_capture`, at the start of a fit)."""
    environment_resolution: int = 32
    """With background 'environment': rows of its equirectangular map (elevation; twice as many
    columns of azimuth)."""
    near_fraction: float | None = 0.0
    """Rays start at `near` from their camera, set at the start of a fit to this fraction of the
    cameras' median distance to the point they look at, so no camera can explain its own
    image with fog right in front of it (0: rays start where they enter the scene box; None:
    `ROOM_NEAR` for a capture in a room, else 0, by `for_capture`)."""
    near: float = 0.0
    """That distance in world units (the fit sets it from `near_fraction`)."""
    bounds_margin: float = 0.1
    """The scene box is the sparse points' 1-99 % box grown on each side by this fraction of its longest side."""
    background_fraction: float = 0.5
    """With a region: the scene box's grids (outside the region) have this fraction of the
    resolutions above along the box's longest side; the region's grids have the resolutions above
    along the region's longest side."""
    region_step_ratio: float = 0.0
    """With a region: distance between samples inside it, in voxels of its density grid (0:
    `step_ratio`); outside it samples are `step_ratio` voxels of the coarse grid apart."""
    region_rays: float = 0.0
    """With a region: this share of each batch is drawn from the rays that pass through it (the
    rest from all rays), so its fine voxels are trained as often as a one-grid fit's are even where
    the region fills a small part of the images (a tabletop in a room)."""
    region_max_vertices: int = 0
    """With a region: its grids' resolutions are scaled down (at every step alike) until its density
    grid has at most this many vertices at the end; 0: as many as `grid_resolution` over the whole
    scene box would have, so the fine grid costs what the one-grid fit's grid costs."""
    checkpoint_every: int = 250
    """Steps between checkpoints."""
    seed: int = 0

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> NerfConfig:
        values = json.loads(text)
        values["upsample_steps"] = tuple(values.get("upsample_steps", ()))
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in values.items() if k in known})

    def grid_resolution_at(self, step: int) -> int:
        """Density-grid resolution (longest side) in force at `step`."""
        stages = len(self.upsample_steps)
        done = sum(1 for s in self.upsample_steps if step >= s)
        if stages == 0:
            return self.grid_resolution
        ratio = (self.grid_resolution / self.grid_resolution_initial) ** (done / stages)
        return int(round(self.grid_resolution_initial * ratio))

    def feature_resolution_at(self, step: int) -> int:
        """Colour-feature grid resolution (longest side) in force at `step`."""
        stages = len(self.upsample_steps)
        if self.feature_resolution_initial <= 0 or stages == 0:
            return self.feature_resolution
        done = sum(1 for s in self.upsample_steps if step >= s)
        ratio = (self.feature_resolution / self.feature_resolution_initial) ** (done / stages)
        return int(round(self.feature_resolution_initial * ratio))


PRESETS = {
    # fast: a diffuse colour grid (no MLP) that grows with the density grid, over a box that
    # takes in the walls; early ray termination in training; the distortion term, which clears
    # fog; in a room, the room's walls as an environment map and rays that start a little away
    # from their camera (docs/fit-nerf.md, "A capture in a room").
    "fast": NerfConfig(
        background="auto",
        near_fraction=None,
        grid_resolution_initial=64,
        grid_resolution=192,
        upsample_steps=(80, 200),
        feature_resolution_initial=64,
        feature_resolution=192,
        feature_channels=3,
        mlp_width=0,
        occupancy_warmup=20,
        transmittance_threshold=1e-3,
        bounds_margin=0.05,
        distortion_weight=0.03,
        region_step_ratio=1.0,
        steps=1000,
    ),
    "quality": NerfConfig(
        background="auto",
        near_fraction=None,
        max_image_side=400,
        grid_resolution_initial=64,
        grid_resolution=320,
        upsample_steps=(150, 400, 800),
        feature_resolution_initial=64,
        feature_resolution=256,
        feature_channels=12,
        mlp_width=64,
        occupancy_warmup=20,
        transmittance_threshold=1e-3,
        bounds_margin=0.05,
        steps=2000,
        rays_per_batch=8192,
        tv_weight=0.0,
        checkpoint_every=500,
    ),
}


ROOM_POINTS = 0.2
"""A capture was taken in a room when at least this fraction of its sparse points lie outside
the scene box: walls and floor seen beyond the region the box keeps (`rays.scene_bounds` ends
it at the cameras' reach)."""

ROOM_NEAR = 0.2
"""`near_fraction` for a capture in a room."""


@dataclasses.dataclass(frozen=True)
class CaptureKind:
    """What `for_capture` found: the share of the sparse points outside the scene box, and
    whether that makes the capture one taken in a room."""

    outside: float
    room: bool


def for_capture(config: NerfConfig, points, bounds) -> tuple[NerfConfig, CaptureKind]:
    """`config` with an 'auto' `background` and a None `near_fraction` set for the capture whose
    sparse `points` (M, 3) gave the scene box `bounds` (2, 3): in a room (`ROOM_POINTS`),
    'environment' and `ROOM_NEAR` (the walls beyond the box get the environment map, and no
    camera hides fog in front of itself); elsewhere 'learned' and 0. Values set are kept."""
    import numpy as np

    points = np.asarray(points, np.float64).reshape(-1, 3)
    low, high = np.asarray(bounds, np.float64)
    inside = np.all((points >= low) & (points <= high), axis=1)
    outside = float((~inside).mean()) if len(points) else 0.0
    room = outside >= ROOM_POINTS
    background = config.background
    if background == "auto":
        background = "environment" if room else "learned"
    near = config.near_fraction
    if near is None:
        near = ROOM_NEAR if room else 0.0
    return dataclasses.replace(config, background=background, near_fraction=near), CaptureKind(outside, room)


def preset_config(name: str, **overrides) -> NerfConfig:
    """A preset with some fields replaced (None values are ignored)."""
    return dataclasses.replace(PRESETS[name], **{k: v for k, v in overrides.items() if v is not None})
