"""The region fit-nerf fits finely (`--region`): parsed from text, resolved to a box (2, 3)
inside the scene box, and checked against the views that must see it.

    scene                 no region: one grid over the scene box (before regions existed)
    auto                  `prompts` when a prompts.json is given, else `scene`
    prompts               around the prompted objects: each object's prompt rays (>= 2 views)
                          triangulated to one point (least squares), a cube of half-size
                          `margin` around it (larger when the prompt's inscribed radius says the
                          object is), the box holding every object's cube
    support:H             the support plane z = 0 (capture-poses levels the scene on it): the
                          1-99 % xy extent of the sparse points within SUPPORT_TOLERANCE of
                          it, from z = -0.1 H to z = H
    X0,Y0,Z0,X1,Y1,Z1     that box (world units)

Every box is clipped to the scene box; one that misses it, or that fewer than two views see,
is a one-line error.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from fignetctl.core.containers import require_regular_file
from fignetctl.errors import FignetError, FormatError, SettingError

KINDS = ("auto", "scene", "prompts", "support:H", "X0,Y0,Z0,X1,Y1,Z1")
SUPPORT_TOLERANCE = 0.005
"""Sparse points within this fraction of the scene box's longest side of z = 0 are on the support."""
MIN_SUPPORT_POINTS = 20
MIN_REGION_SIDE = 0.005
"""A region's sides must be at least this fraction of the scene box's longest side."""
INSCRIBED_RADII = 2.0
"""With prompts.json's `inscribed_radius_px`, an object's cube is at least this many of its
inscribed radii (in world units at the triangulated point) in half-size."""


@dataclasses.dataclass(frozen=True)
class RegionRequest:
    """What --region asked for: kind 'scene', 'prompts', 'support' (with height) or 'box'."""

    kind: str
    box: tuple | None = None
    height: float | None = None
    prompts: str | None = None
    margin: float = 0.12

    def describe(self) -> str:
        if self.kind == "support":
            return f"support:{self.height:g}"
        if self.kind == "box":
            return ",".join(f"{x:g}" for x in self.box)
        return self.kind


def parse_region(text: str, prompts=None, margin: float = 0.12) -> RegionRequest:
    """--region text (and --prompts, --region-margin) -> RegionRequest; SettingError in one line."""
    value = str(text).strip().lower()
    usage = f"`region` {text!r}: give one of {', '.join(KINDS)}"
    if value == "auto":
        value = "prompts" if prompts is not None else "scene"
    if value == "scene":
        return RegionRequest("scene", margin=margin)
    if value == "prompts":
        if prompts is None:
            raise SettingError("`region` prompts needs `prompts` (a prompts.json; render-views writes one)")
        return RegionRequest("prompts", prompts=str(prompts), margin=margin)
    if value.startswith("support:"):
        height = _number(value.split(":", 1)[1])
        if height is None or height <= 0:
            raise SettingError(f"`region` {text!r}: support:H needs a positive height H (world units)")
        return RegionRequest("support", height=height, margin=margin)
    numbers = [_number(x) for x in value.split(",")]
    if len(numbers) != 6 or any(x is None for x in numbers):
        raise SettingError(usage)
    low, high = np.array(numbers[:3]), np.array(numbers[3:])
    if (high <= low).any():
        raise SettingError(
            f"`region` {text!r}: the box's upper corner must exceed its lower one on every axis"
        )
    return RegionRequest("box", box=tuple(numbers), margin=margin)


def _number(text):
    try:
        number = float(text)
    except (TypeError, ValueError, OverflowError):
        return None
    return number if math.isfinite(number) and abs(number) <= 1e6 else None


def resolve_region(request: RegionRequest, cameras, bounds) -> np.ndarray | None:
    """The region's box (2, 3) inside the scene box `bounds`, or None for 'scene'."""
    bounds = np.asarray(bounds, np.float64)
    if request.kind == "scene":
        return None
    if request.kind == "box":
        box = np.array(request.box, np.float64).reshape(2, 3)
    elif request.kind == "support":
        box = support_box(cameras, bounds, request.height)
    else:
        box = prompts_box(request.prompts, cameras, request.margin)
    clipped = np.stack([np.maximum(box[0], bounds[0]), np.minimum(box[1], bounds[1])])
    if (clipped[1] <= clipped[0]).any():
        raise FignetError(
            f"the region {_text(box)} lies outside the scene box {_text(bounds)}; "
            "give a box the cameras see (the scene box is where the sparse points are)"
        )
    smallest = MIN_REGION_SIDE * float((bounds[1] - bounds[0]).max())
    if (clipped[1] - clipped[0] < smallest).any():
        raise FignetError(
            f"the region {_text(clipped)} is thinner than {smallest:.3g} world units "
            f"({MIN_REGION_SIDE:g} of the scene box) on some axis; give a larger box"
        )
    return clipped


def _text(box) -> str:
    return "[" + ", ".join(f"{x:.3g}" for x in np.asarray(box).reshape(-1)) + "]"


def support_box(cameras, bounds, height: float) -> np.ndarray:
    """The support plane z = 0's 1-99 % xy extent in the sparse points, z from -0.1 H to H."""
    points = np.asarray(cameras.points, np.float64).reshape(-1, 3)
    tolerance = SUPPORT_TOLERANCE * float((bounds[1] - bounds[0]).max())
    on_plane = points[np.abs(points[:, 2]) <= tolerance]
    if len(on_plane) < MIN_SUPPORT_POINTS:
        raise FignetError(
            f"region support:{height:g}: {len(on_plane)} sparse points lie on the support plane z = 0 "
            f"(need {MIN_SUPPORT_POINTS}); run capture-poses, which levels the scene on it, or give a box"
        )
    low, high = np.percentile(on_plane[:, :2], 1, axis=0), np.percentile(on_plane[:, :2], 99, axis=0)
    return np.array([[low[0], low[1], -0.1 * height], [high[0], high[1], height]])


def read_all_prompts(path, cameras) -> list:
    """prompts.json (format fignetctl.prompts v1) -> [(name, [(view index, u, v, inscribed
    radius px or None), ...])] of every object; a FormatError in one line when it is not one."""
    path = require_regular_file(path, "prompts")
    result = []
    try:
        document = json.loads(Path(path).read_text())
        if document.get("format") != "fignetctl.prompts" or document.get("format_version") != 1:
            raise ValueError("not format fignetctl.prompts version 1")
        for item in document["objects"]:
            points = []
            for point in item["points"]:
                view, u, v = cameras.index_of(str(point["image"])), int(point["u"]), int(point["v"])
                if not (0 <= u < cameras.width and 0 <= v < cameras.height):
                    raise ValueError(f"pixel {u},{v} is outside the {cameras.width}x{cameras.height} image")
                radius = point.get("inscribed_radius_px")
                usable = isinstance(radius, (int, float)) and math.isfinite(radius) and radius > 0
                points.append((view, u, v, float(radius) if usable else None))
            result.append((str(item["name"]), points))
    except (
        OSError,
        ValueError,
        KeyError,
        TypeError,
        AttributeError,
        OverflowError,
        RecursionError,
        FormatError,
    ) as error:
        raise FormatError(f"{path}: not a usable prompts.json ({type(error).__name__}: {error})") from None
    if not result:
        raise FignetError(f"{path}: holds no objects")
    return result


def triangulate(origins, directions) -> tuple:
    """The point closest to every ray (least squares) and its largest distance to one."""
    units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    projectors = np.eye(3) - units[:, :, None] * units[:, None, :]
    lhs, rhs = projectors.sum(0), np.einsum("nij,nj->i", projectors, origins)
    if np.linalg.cond(lhs) > 1e8:
        return None, math.inf
    point = np.linalg.solve(lhs, rhs)
    offsets = point - origins
    distances = np.linalg.norm(offsets - (offsets * units).sum(1, keepdims=True) * units, axis=1)
    return point, float(distances.max())


def prompts_box(prompts, cameras, margin: float) -> np.ndarray:
    """The box holding a cube of half-size `margin` around each prompted object's triangulated
    prompt rays (larger for an object whose inscribed radius says it is larger)."""
    from fignetctl.core.pinhole import camera_directions

    lows, highs = [], []
    for name, points in read_all_prompts(prompts, cameras):
        views = sorted({view for view, *_ in points})
        if len(views) < 2:
            raise FignetError(f"{prompts}: object {name!r} is prompted in {len(views)} view; give at least 2")
        origins, directions = [], []
        for view, u, v, _ in points:
            c2w = cameras.c2w[view]
            directions.append(camera_directions(cameras.K[view], np.array(u), np.array(v)) @ c2w[:3, :3].T)
            origins.append(c2w[:3, 3])
        origins, directions = np.array(origins), np.array(directions).reshape(-1, 3)
        centre, spread = triangulate(origins, directions)
        depths = None if centre is None else np.einsum("nj,nj->n", centre - origins, directions)
        if centre is None or (depths <= 0).any():
            raise FignetError(
                f"{prompts}: the prompts of {name!r} do not meet in front of their cameras; "
                "check that they mark the same object in these cameras' images"
            )
        half = margin
        for (view, u, v, radius), depth in zip(points, depths):
            if radius is not None:
                focal = math.sqrt(cameras.K[view][0, 0] * cameras.K[view][1, 1])
                half = max(half, INSCRIBED_RADII * radius * depth / focal)
        if spread > half:
            raise FignetError(
                f"{prompts}: the prompt rays of {name!r} pass {spread:.3g} world units from their "
                f"common point, more than the region's half-size {half:.3g}; check the prompts or "
                "raise `region_margin`"
            )
        lows.append(centre - half)
        highs.append(centre + half)
    return np.stack([np.min(lows, axis=0), np.max(highs, axis=0)])


def ray_hits(origins, directions, box):
    """(R,) bool numpy: the rays (numpy (R, 3) each) pass through the box (2, 3) in front of their origin."""
    import torch

    from fignetctl.core.nerf.rays import ray_box_intersection

    o = torch.as_tensor(np.asarray(origins, np.float64).reshape(-1, 3))
    d = torch.as_tensor(np.asarray(directions, np.float64).reshape(-1, 3))
    low, high = (torch.as_tensor(np.asarray(b, np.float64)) for b in box)
    near, far = ray_box_intersection(o, d, low, high)
    return (far > near).numpy()


def region_pixels(cameras, index: int, box) -> np.ndarray:
    """(H, W) bool: the pixels of view `index` whose rays pass through the box."""
    from fignetctl.core.pinhole import pixel_rays

    origins, directions = pixel_rays(cameras.K[index], cameras.c2w[index], cameras.width, cameras.height)
    return ray_hits(origins, directions, box).reshape(cameras.height, cameras.width)


def check_seen(box, cameras, indices, at_least: int = 2) -> None:
    """A one-line error unless at least `at_least` of the views `indices` see part of the box."""
    seen = sum(bool(region_pixels(cameras, int(i), box).any()) for i in indices)
    if seen < at_least:
        raise FignetError(
            f"the region {_text(box)} is seen by {seen} of the {len(indices)} training views "
            f"(need {at_least}); give a box in front of the cameras"
        )
