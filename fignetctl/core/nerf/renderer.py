"""Sampling along rays and volume rendering, apart from any field.

A field here is anything with `density(points (P,3)) -> (P,)` and
`colour(points (P,3), directions (P,3)) -> (P,3)`; an occupancy is anything with
`lookup(points) -> (P,) bool`. A field with two levels (GridField with a region) also has
`level_order(points) -> (order, split)`, and then its `density` and the occupancy's `lookup`
also take the points in that order with `split` of them on the first level. Compositing
(Max 1995, NeRF):

    αᵢ = 1 − exp(−σᵢ δᵢ),  Tᵢ = exp(−Σ_{j<i} σⱼ δⱼ),  wᵢ = Tᵢ αᵢ
    C = Σ wᵢ cᵢ + (1 − Σ wᵢ) · background,  opacity = Σ wᵢ,  depth = Σ wᵢ tᵢ / Σ wᵢ

with δᵢ the world distance between samples and tᵢ the ray parameter of sample i (z-depth for
rays whose direction has camera-frame z = 1, see rays.py).
"""

from __future__ import annotations

import dataclasses

import torch

from fignetctl.core.nerf.rays import ray_box_intersection


@dataclasses.dataclass
class RaySamples:
    """Samples along R rays, S per ray (padded), in order along each ray."""

    t: torch.Tensor  # (R, S) ray parameter of each sample
    points: torch.Tensor  # (R, S, 3) world positions
    step: torch.Tensor  # (R,) world distance between neighbouring samples, or (R, S) per sample (region)
    valid: torch.Tensor  # (R, S) inside [near, far)


class RegionSteps(float):
    """A step length (world units) for the space outside a region that also carries the region
    (`low`, `high`, (3,) tensors) and the finer step inside it (`fine`): what
    `NerfModel.step_length` is for a field with a region, so every caller of
    `sample_along_rays(..., model.step_length)` samples the region at the fine step. As a
    number it is the coarse step."""

    def __new__(cls, step: float, low, high, fine: float):
        value = super().__new__(cls, step)
        value.low, value.high, value.fine = low, high, float(fine)
        return value


def sample_along_rays(origins, directions, low, high, step_length: float, jitter=None, near: float = 0.0):
    """Samples every `step_length` (world units) inside the box and at least `near` (world
    units) from the origin; `jitter` (R,) in [0, 1) offsets the first sample (training), else
    samples start half a step in. With a `RegionSteps`, samples inside its region are at most
    `fine` apart and those outside at most `step_length` apart, each with the length of ray it
    stands for as its step ((R, S) `step`; they add up to the ray's chord through the box)."""
    near_box, far = ray_box_intersection(origins, directions, low, high)
    norms = directions.norm(dim=-1).clamp(min=1e-12)
    near = torch.maximum(near_box, near / norms) if near > 0 else near_box
    offset = torch.full_like(near, 0.5) if jitter is None else jitter
    if isinstance(step_length, RegionSteps):
        return _sample_with_region(origins, directions, near, far, norms, offset, step_length)
    step_t = step_length / norms
    count = int(torch.clamp(((far - near) / step_t).max().ceil(), min=1).item()) if len(origins) else 1
    index = torch.arange(count, device=origins.device, dtype=origins.dtype)
    t = near[:, None] + (index[None, :] + offset[:, None]) * step_t[:, None]
    valid = t < far[:, None]
    points = origins[:, None, :] + t[..., None] * directions[:, None, :]
    return RaySamples(t=t, points=points, step=step_t * norms, valid=valid)


def _sample_with_region(origins, directions, near, far, norms, offset, steps: RegionSteps):
    """Three segments per ray: before the region, in it (fine) and after it, each cut into
    ceil(length / step) equal pieces with one sample in each (at `offset` of it), so that a
    segment's samples add up to its length; a ray's samples in order, padding after them."""
    low, high = (b.to(device=origins.device, dtype=origins.dtype) for b in (steps.low, steps.high))
    region_near, region_far = ray_box_intersection(origins, directions, low, high)
    region_near, region_far = torch.maximum(region_near, near), torch.minimum(region_far, far)
    hits = region_far > region_near
    coarse_t, fine_t = float(steps) / norms, steps.fine / norms
    segments = (
        (near, torch.where(hits, region_near, far), coarse_t),
        (region_near, torch.where(hits, region_far, region_near), fine_t),
        (torch.where(hits, region_far, far), far, coarse_t),
    )
    starts, pieces, counts = [], [], []
    for start, end, step_t in segments:
        length = (end - start).clamp(min=0)
        count = torch.ceil(length / step_t - 1e-6).clamp(min=0)
        starts.append(start[:, None])
        pieces.append((length / count.clamp(min=1))[:, None])
        counts.append(count[:, None])
    first, second = counts[0], counts[0] + counts[1]
    total = second + counts[2]
    width = max(1, int(total.max().item())) if len(origins) else 1
    slot = torch.arange(width, device=origins.device, dtype=origins.dtype)[None, :]
    # which segment each slot of a row falls in, and its index within that segment
    in_first, in_second = slot < first, slot < second
    pick = lambda values: torch.where(in_first, values[0], torch.where(in_second, values[1], values[2]))
    local = slot - torch.where(in_first, 0.0, torch.where(in_second, first, second))
    piece = pick(pieces)
    valid = slot < total
    t = torch.where(valid, pick(starts) + (local + offset[:, None]) * piece, far[:, None])
    step = torch.where(valid, piece * norms[:, None], torch.zeros_like(piece))
    points = origins[:, None, :] + t[..., None] * directions[:, None, :]
    return RaySamples(t=t, points=points, step=step, valid=valid)


def per_sample(step, rows=None, cols=None):
    """A RaySamples step as (R, S)-broadcastable, or at samples (rows, cols)."""
    if rows is None:
        return step if step.dim() == 2 else step[:, None]
    return step[rows, cols] if step.dim() == 2 else step[rows]


def composite(sigma, step, t, background, colour_of=None, weight_threshold=0.0):
    """Volume rendering of densities `sigma` (R, S) at spacing `step` (R,) or (R, S).

    colour_of(mask (R, S) bool) -> (n, 3) colours of the masked samples; only samples with
    weight above `weight_threshold` are coloured. background : (3,) or (R, 3).
    returns rgb (R, 3), depth (R,) (Σ w t / Σ w, 0 where nothing is hit), opacity (R,), weights (R, S)
    """
    optical = sigma * per_sample(step)
    alpha = 1.0 - torch.exp(-optical)
    transmittance = torch.exp(-(torch.cumsum(optical, dim=-1) - optical))
    weights = transmittance * alpha
    opacity = weights.sum(dim=-1)
    depth = (weights * t).sum(dim=-1) / opacity.clamp(min=1e-10)
    depth = torch.where(opacity > 1e-6, depth, torch.zeros_like(depth))
    rgb = (1.0 - opacity)[:, None] * background
    if colour_of is not None:
        mask = weights > weight_threshold
        if mask.any():
            colours = colour_of(mask)
            rgb = rgb + torch.zeros_like(rgb).index_put(
                (mask.nonzero()[:, 0],), weights[mask][:, None] * colours, accumulate=True
            )
    return rgb, depth, opacity, weights


def distortion(weights, t, step, scale: float = 1.0):
    """The distortion loss of Mip-NeRF 360 (Barron et al. 2022, eq. 15) per ray (R,): small
    when a ray's weight sits on one short stretch of it (one surface), large when it is spread
    along the ray or split between surfaces far apart. Sample i stands for the interval of length
    `step` ((R,) or (R, S)) centred at `t` (R, S), its distance along the ray, both in world
    units and divided by `scale`:

        Σᵢ Σⱼ wᵢ wⱼ |mᵢ − mⱼ| + ⅓ Σᵢ wᵢ² δᵢ

    The double sum in O(S) with the samples in order along each ray (as sample_along_rays
    gives them; padding has weight 0): 2 Σᵢ wᵢ (mᵢ Σ_{j<i} wⱼ − Σ_{j<i} wⱼ mⱼ)."""
    middle = t / scale
    width = per_sample(step).expand_as(t) / scale
    before = torch.cumsum(weights, dim=-1) - weights
    moment_before = torch.cumsum(weights * middle, dim=-1) - weights * middle
    between = 2.0 * (weights * (middle * before - moment_before)).sum(dim=-1)
    return between + (weights.pow(2) * width).sum(dim=-1) / 3.0


def median_depth(weights, t, length, opacity):
    """(R,) the ray parameter t at which the ray has lost half the light it loses in all (0
    where nothing is hit), each sample's weight spread evenly over the step centred on it.
    Unlike Σ w t / Σ w, a faint haze in front of a surface (or a faint wall behind it) does not
    move it off the surface.

    weights, t : (R, S); length : (R, S)-broadcastable, the ray-parameter length of each step"""
    weights = weights.detach()
    cumulative = torch.cumsum(weights, dim=-1)
    half = 0.5 * opacity.detach()[:, None]
    index = (cumulative < half).sum(dim=-1, keepdim=True).clamp(max=t.shape[-1] - 1)
    before = (cumulative - weights).gather(-1, index)
    fraction = ((half - before) / weights.gather(-1, index).clamp(min=1e-12)).clamp(0.0, 1.0)
    length = torch.broadcast_to(length, t.shape).gather(-1, index)
    depth = (t.gather(-1, index) + (fraction - 0.5) * length)[:, 0]
    return torch.where(opacity.detach() > 1e-6, depth, torch.zeros_like(depth))


def render_samples(
    field,
    occupancy,
    samples: RaySamples,
    directions,
    background,
    warp=None,
    weight_threshold=0.0,
    transmittance_threshold=0.0,
):
    """Query the field at the samples (through `warp` when given) and composite.

    warp(points (P,3)) -> points (P,3), or -> (points, directions) to also turn the view
    directions; applied to every sample point before the occupancy and field queries.
    transmittance_threshold > 0 (training): a gradient-free density pass first drops the
    samples behind which less than this much light is left (early ray termination), so the
    differentiable pass and its backward only see the samples that matter.
    """
    R, S = samples.valid.shape
    candidate = samples.valid
    flat_index = candidate.nonzero(as_tuple=True)
    query = samples.points[flat_index]
    query_directions = directions[flat_index[0]]
    if warp is not None and len(query):
        warped = warp(query)
        if isinstance(warped, tuple):
            query, query_directions = warped
        else:
            query = warped
    rows, cols = flat_index
    # with a region, the samples are ordered by level once, so each query of the field below
    # splits them by slicing instead of searching (`split` of them lie outside the region)
    split, levels = None, field.level_order(query) if hasattr(field, "level_order") else None
    if levels is not None:
        order, split = levels
        rows, cols, query, query_directions = rows[order], cols[order], query[order], query_directions[order]

    def density(points):
        return field.density(points) if split is None else field.density(points, split)

    def kept(mask):
        nonlocal rows, cols, query, query_directions, split
        if split is not None:
            split = int(mask[:split].sum())
        rows, cols, query, query_directions = rows[mask], cols[mask], query[mask], query_directions[mask]

    if occupancy is not None:
        kept(occupancy.lookup(query) if split is None else occupancy.lookup(query, split))
    if transmittance_threshold > 0 and len(query):
        with torch.no_grad():
            optical = torch.zeros(R, S, device=samples.t.device, dtype=samples.t.dtype)
            optical[rows, cols] = density(query) * per_sample(samples.step, rows, cols)
            before = torch.cumsum(optical, dim=-1) - optical
            kept((before < -torch.log(torch.tensor(transmittance_threshold)))[rows, cols])
    sigma = torch.zeros(R, S, device=samples.t.device, dtype=samples.t.dtype)
    if len(query):
        sigma = sigma.index_put((rows, cols), density(query))
    lookup = torch.full((R, S), -1, dtype=torch.long, device=sigma.device)
    lookup[rows, cols] = torch.arange(len(rows), device=sigma.device)

    def colour_of(mask):  # in the mask's order, which mixes the levels: the field orders them
        chosen = lookup[mask]
        return field.colour(query[chosen], query_directions[chosen])

    return composite(sigma, samples.step, samples.t, background, colour_of, weight_threshold)
