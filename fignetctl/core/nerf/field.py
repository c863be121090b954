"""The radiance field: a dense density grid and a coarser colour-feature grid with a tiny MLP
(DVGO-like), and the occupancy grid that lets the renderer skip empty space.

Both grids span the scene box with their vertices on its faces (trilinear interpolation,
`grid_sample(align_corners=True)`); voxels are cubic, so a flat box has fewer vertices along
its short sides. Density σ (1 / world unit) = softplus(raw + shift) / reference voxel size,
which makes the raw values independent of the scene's scale.
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


class GridField(nn.Module):
    """F(x, d) -> (σ, rgb) on a box. `density` and `colour` take world points."""

    def __init__(self, bounds, config, density_resolution=None, feature_resolution=None):
        super().__init__()
        bounds = torch.as_tensor(np.asarray(bounds, np.float64), dtype=torch.float32)
        self.register_buffer("bounds", bounds)
        size = float((bounds[1] - bounds[0]).max())
        self.reference_voxel = size / (config.grid_resolution - 1)
        # softplus(shift) * step / reference_voxel = -log(1 - alpha_init)
        self.density_shift = math.log(math.expm1(-math.log(1.0 - config.alpha_init) / config.step_ratio))
        resolution = config.grid_resolution_initial if density_resolution is None else density_resolution
        self.density_grid = nn.Parameter(torch.zeros(1, 1, *grid_shape(bounds.numpy(), resolution)))
        if feature_resolution is None:
            feature_resolution = config.feature_resolution_at(0)
        features = torch.zeros(1, config.feature_channels, *grid_shape(bounds.numpy(), feature_resolution))
        self.feature_grid = nn.Parameter(features)
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
    def normalize(self, points):
        """World (P, 3) -> [-1, 1] box coordinates (outside the box: beyond ±1)."""
        low, high = self.bounds[0], self.bounds[1]
        return (points - low) / (high - low) * 2.0 - 1.0

    def inside(self, points):
        """(P,) bool: the point lies in the closed box."""
        return ((points >= self.bounds[0]) & (points <= self.bounds[1])).all(dim=-1)

    @property
    def voxel_size(self) -> float:
        """Edge of a density-grid voxel (world units) at the current resolution."""
        size = (self.bounds[1] - self.bounds[0]).max().item()
        return size / (max(self.density_grid.shape[2:]) - 1)

    # -- the field --------------------------------------------------------------------------
    def raw_to_density(self, raw):
        return F.softplus(raw + self.density_shift) / self.reference_voxel

    def density(self, points):
        """σ (P,) at world points (P, 3); 0 outside the box."""
        raw = sample_grid(self.density_grid, self.normalize(points))[:, 0]
        return torch.where(self.inside(points), self.raw_to_density(raw), torch.zeros_like(raw))

    def colour(self, points, directions):
        """RGB (P, 3) in [0, 1] at world points seen along directions (P, 3), any length."""
        features = sample_grid(self.feature_grid, self.normalize(points))
        if self.colour_mlp is None:
            return torch.sigmoid(features[:, :3])
        unit = directions / directions.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        residual = self.colour_mlp(torch.cat([features, spherical_harmonics_degree2(unit)], dim=-1))
        return torch.sigmoid(features[:, :3] + residual)

    def vertex_densities(self):
        """σ at every density-grid vertex, (X, Y, Z)."""
        return self.raw_to_density(self.density_grid[0, 0])

    def upsample_density(self, resolution: int) -> None:
        """Replace the density grid by its trilinear resampling at `resolution` (a new Parameter)."""
        shape = grid_shape(self.bounds.cpu().numpy(), resolution)
        with torch.no_grad():
            grid = F.interpolate(self.density_grid.data, size=shape, mode="trilinear", align_corners=True)
        self.density_grid = nn.Parameter(grid.contiguous())

    def upsample_features(self, resolution: int) -> None:
        """Replace the colour-feature grid by its trilinear resampling at `resolution`."""
        shape = grid_shape(self.bounds.cpu().numpy(), resolution)
        if tuple(shape) == tuple(self.feature_grid.shape[2:]):
            return
        with torch.no_grad():
            grid = F.interpolate(self.feature_grid.data, size=shape, mode="trilinear", align_corners=True)
        self.feature_grid = nn.Parameter(grid.contiguous())

    def total_variation(self):
        """Mean squared difference of neighbouring raw density values."""
        grid = self.density_grid[0, 0]
        return (
            (grid[1:] - grid[:-1]).pow(2).mean()
            + (grid[:, 1:] - grid[:, :-1]).pow(2).mean()
            + (grid[:, :, 1:] - grid[:, :, :-1]).pow(2).mean()
        )


class OccupancyGrid(nn.Module):
    """Which density-grid vertices may hold matter: a point is skipped when its nearest vertex is
    empty. Each vertex is marked from the max opacity of its 3x3x3 neighbourhood, which bounds
    the trilinear density anywhere in the eight voxels around it, so skipping loses nothing
    above the threshold."""

    def __init__(self, bounds, shape):
        super().__init__()
        self.register_buffer("bounds", torch.as_tensor(np.asarray(bounds, np.float64), dtype=torch.float32))
        self.register_buffer("occupied", torch.ones(shape, dtype=torch.bool))

    def refresh(self, field: GridField, step_length: float, threshold: float) -> None:
        with torch.no_grad():
            alpha = 1.0 - torch.exp(-field.vertex_densities() * step_length)
            pooled = F.max_pool3d(alpha[None, None], kernel_size=3, stride=1, padding=1)[0, 0]
            self.occupied = pooled > threshold

    def lookup(self, points):
        """(P,) bool for world points (P, 3); False outside the box."""
        low, high = self.bounds[0], self.bounds[1]
        shape = torch.tensor(self.occupied.shape, device=points.device)
        index = torch.round((points - low) / (high - low) * (shape - 1)).long()
        inside = ((index >= 0) & (index < shape)).all(dim=-1)
        index = torch.minimum(index.clamp(min=0), shape - 1)
        return inside & self.occupied[index[:, 0], index[:, 1], index[:, 2]]

    @property
    def fraction(self) -> float:
        return float(self.occupied.float().mean())
