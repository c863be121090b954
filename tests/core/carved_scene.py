"""A density field for extraction tests without training a NeRF: space carving of a rendered
capture's ground-truth depth (a point is solid when no view sees past it), and a nerf.pt that
holds that field as its density grid."""

import numpy as np

from fignetctl.core import pinhole


def carved_density(depth, cameras, tolerance=0.004):
    """density(points (P, 3)) -> (P,): 1000 where every view that sees the point sees it at or
    behind its GT surface (within `tolerance`), else 0. depth : (N, H, W) z-depth."""

    def density(points):
        points = np.asarray(points, np.float64).reshape(-1, 3)
        solid = np.ones(len(points), bool)
        for K, c2w, z_image in zip(cameras.K, cameras.c2w, depth):
            image, z = pinhole.project(K, c2w, points)
            u, v = pinhole.pixel_of(image).T
            seen = (z > 0) & (u >= 0) & (u < z_image.shape[1]) & (v >= 0) & (v < z_image.shape[0])
            surface = np.full(len(points), np.inf)
            surface[seen] = z_image[v[seen], u[seen]]
            solid &= ~(seen & (z < surface - tolerance))
        return np.where(solid, 1000.0, 0.0)

    return density


def carved_nerf(path, depth, cameras, bounds, resolution=96):
    """Write a nerf.pt whose density grid is the carved field sampled on `bounds` (2, 3)."""
    import torch

    from fignetctl.core.nerf.config import NerfConfig
    from fignetctl.core.nerf.field import grid_shape
    from fignetctl.core.nerf.io import save_nerf
    from fignetctl.core.nerf.model import NerfModel

    config = NerfConfig(grid_resolution_initial=resolution, grid_resolution=resolution)
    model = NerfModel(config, bounds)
    shape = grid_shape(np.asarray(bounds), resolution)
    axes = [np.linspace(bounds[0][i], bounds[1][i], shape[i]) for i in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    solid = carved_density(depth, cameras)(points).reshape(shape) > 0
    raw = np.where(solid, 15.0, -20.0).astype(np.float32)
    model.field.density_grid = torch.nn.Parameter(torch.from_numpy(raw)[None, None])
    model.refresh_occupancy()
    save_nerf(path, model)
    return path
