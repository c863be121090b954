"""The radiance field: a dense density grid and a coarser colour-feature grid with a tiny MLP
(DVGO-like), and the occupancy grid that lets the renderer skip empty space.

Both grids span the scene box with their vertices on its faces (trilinear interpolation,
`grid_sample(align_corners=True)`); voxels are cubic, so a flat box has fewer vertices along
its short sides. Density σ (1 / world unit) = softplus(raw + shift) / reference voxel size,
which makes the raw values independent of the scene's scale.

With a region (fit-nerf --region), the field has two levels: fine grids over the region and
coarse grids over the whole box, each point answered by the finest level that holds it; the
occupancy grid follows the same split (docs/fit-nerf.md, "Region").
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn


def grid_shape(bounds, resolution: int) -> tuple:
    """Vertices per axis (x, y, z) for `resolution` along the longest side of the box."""
    size = np.asarray(bounds[1], np.float64) - np.asarray(bounds[0], np.float64)
    voxel = size.max() / (resolution - 1)
    return tuple(int(max(2, math.ceil(s / voxel - 1e-6) + 1)) for s in size)


def sample_grid(grid, normalized):
    """Trilinear samples of a (1, C, X, Y, Z) grid at (P, 3) coordinates in [-1, 1] -> (P, C)."""
    coordinates = normalized.flip(-1).view(1, 1, 1, -1, 3).to(grid.dtype)
    values = F.grid_sample(grid, coordinates, mode="bilinear", padding_mode="border", align_corners=True)
    return values.view(grid.shape[1], -1).t()


def spherical_harmonics_degree2(directions):
    """Real SH basis of degree <= 2 of unit (P, 3) directions -> (P, 9)."""
    x, y, z = directions.unbind(-1)
    return torch.stack(
        [
            torch.full_like(x, 0.28209479),
            -0.48860251 * y,
            0.48860251 * z,
            -0.48860251 * x,
            1.09254843 * x * y,
            -1.09254843 * y * z,
            0.31539157 * (3 * z * z - 1),
            -1.09254843 * x * z,
            0.54627422 * (x * x - y * y),
        ],
        dim=-1,
    )


def background_resolution(config, resolution: int) -> int:
    """Vertices along the scene box's longest side outside a region, when the region's grid
    takes `resolution` (the config's resolution in force): `background_fraction` of it."""
    return max(2, round(resolution * config.background_fraction))


def region_resolution(region, resolution: int, max_vertices: int) -> int:
    """`resolution` along the region's longest side, lowered until the grid has at most
    `max_vertices` vertices (a cube-like region would otherwise cost resolution³)."""
    resolution = max(2, int(resolution))
    while resolution > 2:
        count = math.prod(grid_shape(region, resolution))
        if count <= max_vertices:
            break
        resolution = max(2, min(resolution - 1, int(resolution * (max_vertices / count) ** (1 / 3))))
    return resolution


def _as_box(box) -> torch.Tensor:
    return torch.as_tensor(np.asarray(box, np.float64), dtype=torch.float32)


def _normalize(points, box):
    """World (P, 3) -> [-1, 1] coordinates of `box` (outside the box: beyond ±1)."""
    return (points - box[0]) / (box[1] - box[0]) * 2.0 - 1.0


def _inside(points, box):
    return ((points >= box[0]) & (points <= box[1])).all(dim=-1)


class GridField(nn.Module):
    """F(x, d) -> (σ, rgb) on a box. `density` and `colour` take world points.

    With a `region` (2, 3) inside the box, two levels: a fine density grid and colour grid over
    the region (`region_density_grid`, `region_feature_grid`; `grid_resolution` along the
    region's longest side, capped at `region_max_vertices`), and the coarse grids over the whole
    box (`background_fraction` of the resolution) for every point outside the region. A point in
    the region is answered by the fine grids alone. The colour MLP is shared."""

    def __init__(self, bounds, config, density_resolution=None, feature_resolution=None, region=None):
        super().__init__()
        self.config = config
        bounds = _as_box(bounds)
        self.register_buffer("bounds", bounds)
        # softplus(shift) * step / reference_voxel = -log(1 - alpha_init)
        self.density_shift = math.log(math.expm1(-math.log(1.0 - config.alpha_init) / config.step_ratio))
        if density_resolution is None:
            density_resolution = config.grid_resolution_initial
        if feature_resolution is None:
            feature_resolution = config.feature_resolution_at(0)
        self.has_region = region is not None
        if self.has_region:
            self.register_buffer("region", _as_box(region))
        final = self.level_resolutions(config.grid_resolution)
        self.reference_voxel = float((bounds[1] - bounds[0]).max()) / (final[0] - 1)
        density, features = (
            self.level_resolutions(density_resolution),
            self.level_resolutions(feature_resolution),
        )
        self.density_grid = nn.Parameter(torch.zeros(1, 1, *grid_shape(bounds.numpy(), density[0])))
        self.feature_grid = nn.Parameter(
            torch.zeros(1, config.feature_channels, *grid_shape(bounds.numpy(), features[0]))
        )
        if self.has_region:
            region_box = self.region.numpy()
            self.region_reference_voxel = float((self.region[1] - self.region[0]).max()) / (final[1] - 1)
            self.region_density_grid = nn.Parameter(torch.zeros(1, 1, *grid_shape(region_box, density[1])))
            self.region_feature_grid = nn.Parameter(
                torch.zeros(1, config.feature_channels, *grid_shape(region_box, features[1]))
            )
        if config.mlp_width > 0:
            self.colour_mlp = nn.Sequential(
                nn.Linear(config.feature_channels + 9, config.mlp_width),
                nn.ReLU(inplace=True),
                nn.Linear(config.mlp_width, config.mlp_width),
                nn.ReLU(inplace=True),
                nn.Linear(config.mlp_width, 3),
            )
            nn.init.zeros_(self.colour_mlp[-1].weight)
            nn.init.zeros_(self.colour_mlp[-1].bias)
        else:  # diffuse colour only: the first three features
            self.colour_mlp = None

    # -- geometry of the grids --------------------------------------------------------------
    def level_resolutions(self, resolution: int) -> tuple:
        """Vertices along the longest side of (the scene grid, the region's grid) when the
        config's resolution in force is `resolution` (one entry without a region). The region's
        resolutions are the config's scaled by the one factor that keeps its final density grid
        within `region_max_vertices` (0: the vertices of `grid_resolution` over the scene box)."""
        if not self.has_region:
            return (int(resolution),)
        if not hasattr(self, "_region_scale"):
            config = self.config
            budget = config.region_max_vertices or math.prod(
                grid_shape(self.bounds.cpu().numpy(), config.grid_resolution)
            )
            final = region_resolution(self.region.cpu().numpy(), config.grid_resolution, budget)
            self._region_scale = final / config.grid_resolution
        return (
            background_resolution(self.config, resolution),
            max(2, round(resolution * self._region_scale)),
        )

    def density_grids(self) -> list:
        return [self.density_grid, self.region_density_grid] if self.has_region else [self.density_grid]

    def feature_grids(self) -> list:
        return [self.feature_grid, self.region_feature_grid] if self.has_region else [self.feature_grid]

    def grid_boxes(self) -> list:
        return [self.bounds, self.region] if self.has_region else [self.bounds]

    def reference_voxels(self) -> list:
        voxels = [self.reference_voxel]
        return voxels + [self.region_reference_voxel] if self.has_region else voxels

    @property
    def voxel_size(self) -> float:
        """Edge of a voxel of the scene box's density grid (world units) at the current resolution."""
        size = (self.bounds[1] - self.bounds[0]).max().item()
        return size / (max(self.density_grid.shape[2:]) - 1)

    @property
    def region_voxel_size(self) -> float | None:
        """Edge of a voxel of the region's density grid (None without a region)."""
        if not self.has_region:
            return None
        size = (self.region[1] - self.region[0]).max().item()
        return size / (max(self.region_density_grid.shape[2:]) - 1)

    @property
    def finest_voxel_size(self) -> float:
        return self.voxel_size if not self.has_region else self.region_voxel_size

    # -- the field --------------------------------------------------------------------------
    def raw_to_density(self, raw, level: int = 0):
        return F.softplus(raw + self.density_shift) / self.reference_voxels()[level]

    def _by_level(self, points, query, width, split=None):
        """(P, width) of query(level, points of that level), each point answered by its level.
        `split`: the points come ordered by level, points[:split] outside the region and
        points[split:] in it (as `level_order` orders them); else they are ordered here."""
        if not self.has_region:
            return query(0, points)
        if split is None:
            order, split = self.level_order(points)
            return _unordered(self._by_level(points[order], query, width, split), order)
        parts = (points[:split], points[split:])
        return torch.cat(
            [query(level, p) if len(p) else points.new_zeros(0, width) for level, p in enumerate(parts)]
        )

    def _level_density(self, level, points):
        box = self.grid_boxes()[level]
        raw = sample_grid(self.density_grids()[level], _normalize(points, box))[:, 0]
        sigma = self.raw_to_density(raw, level)
        if level == 1:  # _by_level gives the region's grid only points in the region
            return sigma[:, None]
        return torch.where(_inside(points, box), sigma, torch.zeros_like(sigma))[:, None]

    def level_order(self, points):
        """(order (P,), split): the permutation that puts the points outside the region first
        and those in it after them, and how many are outside; None without a region."""
        return _level_order(points, self.region) if self.has_region else None

    def density(self, points, split=None):
        """σ (P,) at world points (P, 3); 0 outside the box. `split`: as in `_by_level`."""
        return self._by_level(points, self._level_density, 1, split)[:, 0]

    def colour(self, points, directions, split=None):
        """RGB (P, 3) in [0, 1] at world points seen along directions (P, 3), any length.
        `split`: as in `_by_level`."""
        features = self._by_level(
            points,
            lambda level, p: sample_grid(
                self.feature_grids()[level], _normalize(p, self.grid_boxes()[level])
            ),
            self.feature_grid.shape[1],
            split,
        )
        if self.colour_mlp is None:
            return torch.sigmoid(features[:, :3])
        unit = directions / directions.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        residual = self.colour_mlp(torch.cat([features, spherical_harmonics_degree2(unit)], dim=-1))
        return torch.sigmoid(features[:, :3] + residual)

    def vertex_densities(self, level: int = 0):
        """σ at every vertex of a density grid (0: the scene box's, 1: the region's), (X, Y, Z)."""
        return self.raw_to_density(self.density_grids()[level][0, 0], level)

    def _resample(self, name, box, resolution):
        grid = getattr(self, name)
        shape = grid_shape(box.cpu().numpy(), resolution)
        if tuple(shape) == tuple(grid.shape[2:]):
            return
        with torch.no_grad():
            grid = F.interpolate(grid.data, size=shape, mode="trilinear", align_corners=True)
        setattr(self, name, nn.Parameter(grid.contiguous()))

    def upsample_density(self, resolution: int) -> None:
        """Replace the density grids by their trilinear resampling at `resolution` (new Parameters)."""
        names = ("density_grid", "region_density_grid")
        for name, box, res in zip(names, self.grid_boxes(), self.level_resolutions(resolution)):
            self._resample(name, box, res)

    def upsample_features(self, resolution: int) -> None:
        """Replace the colour-feature grids by their trilinear resampling at `resolution`."""
        names = ("feature_grid", "region_feature_grid")
        for name, box, res in zip(names, self.grid_boxes(), self.level_resolutions(resolution)):
            self._resample(name, box, res)

    def total_variation(self):
        """Mean squared difference of neighbouring raw density values (summed over the grids)."""
        total = 0.0
        for grid in self.density_grids():
            grid = grid[0, 0]
            total = total + (
                (grid[1:] - grid[:-1]).pow(2).mean()
                + (grid[:, 1:] - grid[:, :-1]).pow(2).mean()
                + (grid[:, :, 1:] - grid[:, :, :-1]).pow(2).mean()
            )
        return total


def _level_order(points, region):
    """(order (P,), split): the permutation that puts the points outside `region` first and
    those in it after them, and how many are outside."""
    inner = _inside(points, region)
    outer = (~inner).nonzero(as_tuple=True)[0]
    return torch.cat([outer, inner.nonzero(as_tuple=True)[0]]), len(outer)


def _unordered(values, order):
    """`values` of the points `order` picked, put back in the points' own order."""
    return torch.zeros_like(values).index_put((order,), values)


def _lookup(occupied, box, points):
    shape = torch.tensor(occupied.shape, device=points.device)
    index = torch.round((points - box[0]) / (box[1] - box[0]) * (shape - 1)).long()
    inside = ((index >= 0) & (index < shape)).all(dim=-1)
    index = torch.minimum(index.clamp(min=0), shape - 1)
    return inside & occupied[index[:, 0], index[:, 1], index[:, 2]]


class OccupancyGrid(nn.Module):
    """Which density-grid vertices may hold matter: a point is skipped when its nearest vertex is
    empty. Each vertex is marked from the max opacity of its 3x3x3 neighbourhood, which bounds
    the trilinear density anywhere in the eight voxels around it, so skipping loses nothing
    above the threshold. With a region, a second grid over it (`region_occupied`) answers the
    points in the region, as the field does."""

    def __init__(self, bounds, shape, region=None, region_shape=None):
        super().__init__()
        self.register_buffer("bounds", _as_box(bounds))
        self.register_buffer("occupied", torch.ones(shape, dtype=torch.bool))
        self.has_region = region is not None
        if self.has_region:
            self.register_buffer("region", _as_box(region))
            self.register_buffer("region_occupied", torch.ones(region_shape, dtype=torch.bool))

    def refresh(
        self, field: GridField, step_length: float, threshold: float, region_step_length=None
    ) -> None:
        """Re-mark from the field's densities; an opacity is over `step_length` (the region's:
        over `region_step_length`)."""
        with torch.no_grad():
            names = ["occupied", "region_occupied"] if self.has_region else ["occupied"]
            for level, (name, step) in enumerate(zip(names, (step_length, region_step_length))):
                alpha = 1.0 - torch.exp(-field.vertex_densities(level) * step)
                pooled = F.max_pool3d(alpha[None, None], kernel_size=3, stride=1, padding=1)[0, 0]
                setattr(self, name, pooled > threshold)

    def lookup(self, points, split=None):
        """(P,) bool for world points (P, 3); False outside the box. `split`: the points come
        ordered as GridField.level_order orders them, `split` of them outside the region."""
        if not self.has_region:
            return _lookup(self.occupied, self.bounds, points)
        if split is None:
            order, split = _level_order(points, self.region)
            return _unordered(self.lookup(points[order], split), order)
        return torch.cat(
            [
                _lookup(self.occupied, self.bounds, points[:split]),
                _lookup(self.region_occupied, self.region, points[split:]),
            ]
        )

    @property
    def fraction(self) -> float:
        """Occupied share of the scene box's grid."""
        return float(self.occupied.float().mean())

    @property
    def region_fraction(self) -> float | None:
        return float(self.region_occupied.float().mean()) if self.has_region else None
