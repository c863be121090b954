"""Training data: images checked against cameras.npz, downscaled, split, turned into rays."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import torch

from fignetctl.core.cameras import Cameras, check_images_match
from fignetctl.core.media import read_image
from fignetctl.core.pinhole import pixel_rays, scale_intrinsics
from fignetctl.errors import FignetError


@dataclasses.dataclass
class Views:
    """Images (N, H, W, 3) float32 in [0, 1] and their cameras at that size."""

    images: np.ndarray
    cameras: Cameras
    scale: float  # image size / original size

    def split(self, holdout_every: int):
        """(train indices, held-out indices): views 0, k, 2k, ... are held out."""
        n = len(self.images)
        if holdout_every <= 0 or n < 2:
            return np.arange(n), np.zeros(0, int)
        held = np.arange(0, n, holdout_every)
        return np.setdiff1d(np.arange(n), held), held


def downscale_factor(width: int, height: int, max_side: int) -> float:
    return min(1.0, max_side / max(width, height))


def load_views(image_dir, cameras: Cameras, max_side: int) -> Views:
    """Read the cameras' images from `image_dir`, downscaled so the longer side <= max_side."""
    import cv2

    files = check_images_match(cameras, image_dir)
    scale = downscale_factor(cameras.width, cameras.height, max_side)
    width, height = max(1, round(cameras.width * scale)), max(1, round(cameras.height * scale))
    images = np.empty((len(files), height, width, 3), np.float32)
    for i, file in enumerate(files):
        image = read_image(file, cv2.IMREAD_COLOR)
        if (width, height) != (cameras.width, cameras.height):
            image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        images[i] = image[..., ::-1].astype(np.float32) / 255.0
    K = scale_intrinsics(cameras.K, width / cameras.width, height / cameras.height)
    scaled = dataclasses.replace(cameras, K=K, width=width, height=height)
    return Views(images, scaled, width / cameras.width)


def inputs_hash(image_dir, cameras_path) -> str:
    """sha256 over cameras.npz and the bytes of the images it names."""
    from fignetctl.core.cameras import read_cameras

    cameras = read_cameras(cameras_path)
    files = check_images_match(cameras, image_dir, str(cameras_path))
    digest = hashlib.sha256(Path(cameras_path).read_bytes())
    for name, file in zip(cameras.image_names, files):
        digest.update(str(name).encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()


def training_rays(views: Views, indices, device="cpu"):
    """All pixels of the views at `indices`: origins, directions, colours, each (R, 3) float32."""
    if len(indices) == 0:
        raise FignetError("no training views: give more images or a larger holdout interval")
    origins, directions, colours = [], [], []
    for i in indices:
        o, d = pixel_rays(views.cameras.K[i], views.cameras.c2w[i], views.cameras.width, views.cameras.height)
        origins.append(o.reshape(-1, 3))
        directions.append(d.reshape(-1, 3))
        colours.append(views.images[i].reshape(-1, 3))
    as_tensor = lambda parts: torch.as_tensor(np.concatenate(parts), dtype=torch.float32, device=device)
    return as_tensor(origins), as_tensor(directions), as_tensor(colours)
