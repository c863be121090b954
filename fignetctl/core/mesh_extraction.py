"""Meshes of an object and its environment from a density field (paper, "Mesh Extraction").

masks in N views + depth -> 3D points (x = z · K⁻¹ · (u, v, 1)) -> a robust box V_o -> density on
a regular grid in V_o -> marching cubes at σ_thr -> largest component(s), outward faces ->
quadric-error decimation to n_f faces. The environment is the same procedure on a box around
and below V_o with the object's box cut out.

The density is any callable `density(points (P, 3) numpy) -> (P,)`, e.g. `NerfModel.density`
or an analytic function in the tests. The grid is padded with one layer of zero density, so
every surface is closed: where the box cuts through matter (the object's unseen bottom above
the support, the environment's sides and bottom) the mesh gets a flat cap on the box face.

σ_thr can be chosen from the masks (`choose_threshold`): of a few levels spread geometrically
around THRESHOLD, the one whose object mesh's outline best matches the masks in the prompted
views.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np

from fignetctl.core import pinhole
from fignetctl.errors import FignetError

log = logging.getLogger(__name__)

THRESHOLD = 50.0
"""σ_thr (1 / world unit) when it is not chosen from masks, and where the search for it is centred."""


@dataclasses.dataclass(frozen=True)
class ExtractionSettings:
    """How meshes are made from the density field."""

    resolution: int = 96
    """Grid vertices along the longest side of the box (voxels are cubic)."""
    threshold: float = THRESHOLD
    """σ_thr (1 / world unit): the iso-level of marching cubes."""
    auto_threshold: bool = False
    """Choose σ_thr from the masks (`choose_threshold`); `threshold` is then the centre of the
    search, the level of the visual hull (`consistent_box`), and σ_thr when there are no masks."""
    threshold_factors: tuple = (0.25, 0.5, 1.0, 2.0, 4.0)
    """The levels `choose_threshold` tries first, as factors of `threshold`; the best one's two
    geometric midpoints with its neighbours are tried next."""
    threshold_extensions: int = 3
    """When the best of those is the lowest or highest, up to this many more levels are tried
    past it (at the ladder's ratio), while the best stays at the end."""
    threshold_tolerance: float = 0.01
    """A level is chosen over the one nearer `threshold` only when its median outline IoU is
    higher by more than this (closer scores are a tie, not evidence)."""
    faces: int = 1000
    """n_f: faces of each mesh after quadric decimation (0: no decimation)."""
    smoothing: float = 0.5
    """Gaussian blur of the density grid (voxels) before marching cubes (0: none); it removes
    voxel stair-steps, which otherwise stop the decimation short of n_f."""
    padding: float = 0.1
    """V_o is the points' robust box grown on each side by this fraction of its longest side."""
    trim_percent: float = 2.0
    """Unprojected points below this percentile / above 100 minus it (per axis) are outliers."""
    keep_fraction: float = 0.1
    """Connected components smaller than this fraction of the largest (by volume) are dropped."""
    support_clearance_voxels: float = 1.0
    """The object's box starts this many voxels above the support surface found under it (the
    unseen bottom reaches down to there and is capped flat)."""
    passive_margin: float = 0.1
    """The environment box extends this far (world units) beyond V_o horizontally."""
    passive_below: float = 0.05
    """... and this far below the support surface under the object."""
    passive_above: float | None = None
    """... and this far above it (None: V_o's height)."""
    hull_resolution: int = 64
    """Grid vertices along the longest side of the masks' box for the visual-hull refinement (0: off)."""
    hull_reach: float = 0.25
    """The visual hull is sought in the masks' box grown by this fraction of its longest side,
    sideways and upwards (`consistent_box`): the masks' depth points are trimmed
    (`trim_percent`), and an object's corner seen at a slant holds few of them, so their box can
    fall short of the object by more than its padding (the room's brick: 17 mm, 19 % of its
    length)."""
    hull_dilation: int = 3
    """Pixels each mask is grown by before the hull test, so a mask a little short of the object's edge cuts nothing off."""
    hull_mask_margin: float = 0.3
    """When masks are redrawn: GrabCut may still give the object a ring this wide around its
    splat, as a fraction of the splat's size (√area); the NeRF often holds an object's lower
    part only faintly, so its splat falls short there."""
    hull_mask_reach: float = 0.15
    """... but not to pixels whose surface point (the view's depth) is further than this
    fraction of V_o's longest side from the object's voxels: the support around the object,
    which GrabCut would take in where its colour is near the object's (a white ball on a
    speckled tray floor)."""
    hull_mask_clearance: float = 0.1
    """When masks are redrawn, the splat leaves out the object's lowest part, this fraction of
    V_o's height above the support: there the hull also holds the support's own density beside
    the object (seen in one view, hidden behind the object in the others), which would pull a
    piece of the floor into that view's mask. GrabCut fills the object's base in from colour."""
    min_mask_iou: float = 0.5
    """The mesh is refused when its outline and the mask overlap less than this (IoU) in the
    median prompted view (`mask_agreement`): a mesh that does not look like what was prompted."""
    warn_mask_iou: float = 0.8
    """... and a warning names each view where they overlap less than this."""
    warn_extent: float = 0.1
    """A warning names each view and image axis where the mesh's outline is wider or taller than
    the mask (pixel bounding boxes, `outline_extents`) by more than this fraction, or narrower
    or shorter by more than it: the mesh is that much too large or too small there."""
    max_extent: float = 0.3
    """The mesh is refused when, in the median prompted view, its outline's width or height is
    off the mask's by more than this fraction."""
    warn_voxel: float = 1 / 12
    """A warning when the field's finest voxel is larger than this fraction of the object
    mesh's smallest side: its size is then uncertain by up to about a voxel."""
    max_voxel: float = 0.1
    """The mesh is refused when the field's finest voxel is larger than this fraction of its
    smallest side: on a coarse field a mesh's side is off by 0.3-1.1 voxel (the support found
    low, a blob over an opening), which nothing else the extraction sees reveals, so under 10
    voxels across a side can be off by more than 10 %."""
    carve_margin: float | None = 0.5
    """The object's density is cut to the masks' visual hull (`carve`): to zero where a grid
    point projects more than this many pixels (+ 0.5) outside a view's mask (None: no carving)."""
    max_close_voxels: int = 4
    """When the object's decimated mesh is not closed (decimation pinches the handles a noisy
    field's tunnels give the surface), its solid is closed (`closed`) with 1, 2, ... up to
    this many voxels, filling gaps up to twice as wide, until the mesh is."""
    outline_votes: int = 3
    """With carving: the views nobody prompted carve the object too (`outline_masks`: GrabCut
    masks drawn around the first mesh's outline), a point cut when this many of them put it
    outside their masks; 0: only the prompted views carve. Three views at a slant see little of
    an object's sides, so the field's bulges there stay in a hull of the prompted views alone."""
    outline_margin: float = 1.0
    """... each such mask cutting only points more than this many pixels (+ 0.5) outside it
    (`carve`'s margin; their edge is GrabCut's alone, not also the masks' agreement)."""
    outline_min_iou: float = 0.6
    """... a view's GrabCut mask is used only where it overlaps that outline at least this much."""
    outline_occluded: float = 0.02
    """... and only where something in front of the object's box covers at most this fraction
    of the outline (the rendered depth nearer than the box)."""
    free_votes: int = 3
    """With carving: the object's density is cut where this many views (prompted or not) see
    the point more than `free_tolerance` in front of their first surface (`free_space`; 0: off):
    what a hull from above cannot cut, such as a haze over an object's top."""
    free_tolerance: float = 0.03
    """... as a fraction of V_o's longest side (and at least the field's finest voxel: a
    coarse field's depth scatters by about one, which would see through the object's own surface)."""
    fill_hidden: bool = True
    """With carving: the part of the visual hull that every view sees only through the object
    (`hidden`: behind the depth of its surface) is filled, so an object is solid where no view
    saw inside it (a NeRF leaves such space empty: a ball's hidden lower half)."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# -- from masks to a box -------------------------------------------------------------------------


def masked_points(depth, mask, K, c2w):
    """World points (P, 3) float64 of the masked pixels of a z-depth image (H, W) (pinhole.unproject;
    pixels with no finite positive depth are skipped)."""
    depth = np.asarray(depth, np.float64)
    valid = np.asarray(mask, bool) & np.isfinite(depth) & (depth > 0)
    v, u = np.nonzero(valid)
    return pinhole.unproject(K, c2w, u, v, depth[v, u])


def robust_box(points, trim_percent=2.0):
    """(P, 3) -> (2, 3) box of the points between the trim percentiles, after dropping points
    farther from the median than 4 times their median distance to it."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) < 4:
        raise FignetError(
            f"the masks give {len(points)} 3D points; an object needs more (a bigger mask or a depth at the prompt)"
        )
    distance = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    kept = points[distance <= 4.0 * max(np.median(distance), 1e-12)]
    return np.stack(
        [np.percentile(kept, trim_percent, axis=0), np.percentile(kept, 100 - trim_percent, axis=0)]
    )


def check_views_agree(boxes, names, pixels=None):
    """boxes : list of (2, 3) per-view boxes. Each view's box must overlap the union of the
    others' (the masks show one object in 3D); a FignetError names the view that does not (and
    the masks' pixel counts `pixels` when given: tiny masks mean poor masks, not other objects)."""
    if len(boxes) < 2:
        return
    boxes = np.asarray(boxes)
    for i, box in enumerate(boxes):
        others = np.delete(boxes, i, axis=0)
        low, high = others[:, 0].min(0), others[:, 1].max(0)
        size = max((high - low).max(), (box[1] - box[0]).max())
        gap = np.maximum(np.maximum(low - box[1], box[0] - high), 0.0).max()
        if gap > 0.25 * size:
            raise FignetError(
                f"the mask in {names[i]} does not overlap the other views' masks in 3D (a gap of {gap:.3g} world units"
                + (
                    f"; masks of {', '.join(f'{n} px' for n in pixels)} in {', '.join(names)}"
                    if pixels
                    else ""
                )
                + "); are the prompts on the same object? If they are, the masks are wrong (a coarse NeRF's "
                "depth: fit-nerf's `region=prompts`; or give `masks`)"
            )


def padded_box(box, padding):
    """Grow a (2, 3) box by `padding` times its longest side on each side."""
    box = np.asarray(box, np.float64)
    grow = padding * (box[1] - box[0]).max()
    return np.stack([box[0] - grow, box[1] + grow])


# -- density on a grid -------------------------------------------------------------------------


def grid_axes(lower, upper, resolution):
    """Per-axis vertex coordinates of a grid with cubic voxels and `resolution` vertices along
    the box's longest side (starting at `lower`; the box grows up to a whole number of voxels)."""
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    voxel = (upper - lower).max() / (max(int(resolution), 2) - 1)
    counts = np.maximum(np.ceil((upper - lower) / voxel - 1e-6).astype(int) + 1, 2)
    return [lower[i] + voxel * np.arange(counts[i]) for i in range(3)], voxel


def grid_points(axes) -> np.ndarray:
    """(X·Y·Z, 3) the vertices of the grid of `axes` (3 arrays), x slowest."""
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def sample_density(density, axes, chunk=262144):
    """σ on the grid of `axes` (3 arrays) -> (X, Y, Z) float32, by calling density in chunks."""
    shape = tuple(len(a) for a in axes)
    points = grid_points(axes)
    values = np.concatenate(
        [
            np.asarray(density(points[i : i + chunk]), np.float32).reshape(-1)
            for i in range(0, len(points), chunk)
        ]
    )
    values = np.nan_to_num(values, nan=0.0, posinf=np.float32(1e30), neginf=0.0)
    return values.reshape(shape)


def support_height(density, lower, upper, threshold, resolution, depth_below):
    """z of the highest surface under the box's footprint, from vertical density profiles on
    the ring just outside the footprint (median over the ring); None if there is none.

    A profile's surface is the highest z where its density is within 10% of the profile's peak,
    so a support the field holds only faintly (a shiny tray floor, a smear of density below
    `threshold`) is found as well as a solid one; profiles that peak below a tenth of
    `threshold` have no surface.

    lower, upper : (3,) the box; profiles run from lower z − depth_below up to upper z
    """
    lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    size = (upper - lower)[:2].max()
    step = size / max(resolution // 2, 4)
    ring = _footprint_ring(lower[:2] - 0.05 * size, upper[:2] + 0.05 * size, 24)
    z = np.arange(lower[2] - depth_below, upper[2] + step, step / 2)
    points = np.concatenate([np.repeat(ring, len(z), axis=0), np.tile(z, len(ring))[:, None]], axis=1)
    values = np.nan_to_num(np.asarray(density(points), np.float64).reshape(len(ring), len(z)))
    peaks = values.max(axis=1)
    heights = [
        z[np.nonzero(column >= 0.9 * peak)[0].max()]
        for column, peak in zip(values, peaks)
        if peak > 0.1 * threshold
    ]
    if len(heights) < len(ring) // 3:
        return None
    return float(np.median(heights))


def _footprint_ring(low, high, per_side):
    t = np.linspace(0.0, 1.0, per_side, endpoint=False)
    (x0, y0), (x1, y1) = low, high
    sides = [
        np.stack([x0 + t * (x1 - x0), np.full_like(t, y0)], 1),
        np.stack([np.full_like(t, x1), y0 + t * (y1 - y0)], 1),
        np.stack([x1 - t * (x1 - x0), np.full_like(t, y1)], 1),
        np.stack([np.full_like(t, x0), y1 - t * (y1 - y0)], 1),
    ]
    return np.concatenate(sides)


# -- grid to mesh ------------------------------------------------------------------------------


def marching_cubes(values, axes, threshold):
    """Closed surface at σ = threshold of a (X, Y, Z) grid: the grid is padded with zero
    density so the surface is capped where matter reaches the box. Returns vertices (V, 3) in
    world units and faces (F, 3) int64 facing outward (positive signed volume)."""
    from skimage import measure

    values = np.asarray(values, np.float32)
    if not np.isfinite(threshold) or threshold <= 0:
        raise FignetError(f"the density threshold must be a positive number, got {threshold}")
    if values.max() <= threshold:
        raise FignetError(
            f"no density above the threshold {threshold:g} in the volume (max {values.max():.3g}); "
            "lower the `threshold` or check the `box` or the prompts"
        )
    padded = np.pad(values, 1, constant_values=0.0)
    try:
        vertices, faces, _, _ = measure.marching_cubes(padded, level=float(threshold))
    except (ValueError, RuntimeError) as error:
        raise FignetError(f"marching cubes found no surface ({error})") from None
    voxel = axes[0][1] - axes[0][0]
    origin = np.array([a[0] for a in axes]) - voxel
    vertices = origin + vertices * voxel
    faces = faces.astype(np.int64)
    if signed_volume(vertices, faces) < 0:
        faces = faces[:, ::-1]
    return vertices, faces


def signed_volume(vertices, faces):
    """Signed volume of a closed triangle mesh (positive when faces are counter-clockwise
    seen from outside). vertices : (V, 3); faces : (F, 3)."""
    triangles = np.asarray(vertices, np.float64)[np.asarray(faces)]
    return float(
        np.einsum("ij,ij->i", triangles[:, 0], np.cross(triangles[:, 1], triangles[:, 2])).sum() / 6.0
    )


def keep_large_components(vertices, faces, keep_fraction=0.1, log_level=logging.INFO):
    """Drop connected components whose |volume| (area for open pieces) is below `keep_fraction`
    of the largest's; each kept component faces outward (logged at `log_level`). Returns a
    trimesh.Trimesh."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=True)
    parts = mesh.split(only_watertight=False)
    if len(parts) == 0:
        raise FignetError("marching cubes found no surface")
    sizes = np.array([abs(signed_volume(p.vertices, p.faces)) if p.is_watertight else 0.0 for p in parts])
    if sizes.max() <= 0:
        sizes = np.array([p.area for p in parts])
    kept = [p for p, s in zip(parts, sizes) if s >= keep_fraction * sizes.max()]
    for part in kept:
        if signed_volume(part.vertices, part.faces) < 0:
            part.invert()
    log.log(log_level, "kept %d of %d connected components", len(kept), len(parts))
    return trimesh.util.concatenate(kept) if len(kept) > 1 else kept[0]


def decimate(mesh, faces, keep_fraction=0.1):
    """Quadric-error decimation (Garland–Heckbert) to at most `faces` faces (0: unchanged).
    Decimation can pinch a closed surface (two sheets collapsed onto one edge, a face glued to
    its reverse); a closed input then stays closed (`unpinched`), and the slivers cut off at a
    pinch below `keep_fraction` of the largest part's volume are dropped."""
    import trimesh

    if not faces or len(mesh.faces) <= faces:
        return mesh
    simplified = mesh.simplify_quadric_decimation(face_count=int(faces))
    simplified.remove_unreferenced_vertices()
    if len(simplified.faces) == 0:
        raise FignetError(f"decimation to {faces} faces left nothing; ask for more faces")
    if mesh.is_watertight and not simplified.is_watertight:
        parts = trimesh.Trimesh(*unpinched(simplified.vertices, simplified.faces), process=False).split(
            only_watertight=False
        )
        volumes = np.array([abs(signed_volume(part.vertices, part.faces)) for part in parts])
        kept = [part for part, volume in zip(parts, volumes) if volume >= keep_fraction * volumes.max()]
        simplified = trimesh.util.concatenate(kept) if len(kept) > 1 else kept[0]
    if signed_volume(simplified.vertices, simplified.faces) < 0:
        simplified.invert()
    return simplified


def closed(values, threshold, voxels) -> np.ndarray:
    """`values` (a density grid) with the gaps of its solid (> `threshold`) up to about
    2 × `voxels` wide filled (a morphological closing) and its enclosed voids filled, both
    raised to 2 × threshold: a noisy field leaves tunnels and bubbles inside an object, which
    give its surface handles that decimation pinches, and a solid object has none."""
    from scipy import ndimage

    solid = values > threshold
    structure = ndimage.generate_binary_structure(3, 1)
    padded = np.pad(solid, voxels)
    filled = ndimage.binary_closing(padded, structure, iterations=voxels)[(slice(voxels, -voxels),) * 3]
    filled = ndimage.binary_fill_holes(filled | solid)
    return np.where(filled & ~solid, 2 * threshold, values).astype(values.dtype)


def unpinched(vertices, faces):
    """(vertices, faces) of a closed surface with its pinches taken apart: faces glued to their
    own reverse are dropped, the faces round an edge of more than two are paired with their
    neighbours in angle about it (`_radial_pairs`), and a vertex where faces meet in separate
    fans (across such an edge, or at a single point) becomes one vertex per fan, at the same
    place. Afterwards every edge has two faces, so the mesh is watertight where its only
    defects were pinches. Vertices are renumbered."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    _, copy, copies = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    faces = faces[copies[copy.reshape(-1)] == 1]
    flat = faces.reshape(-1)  # corner c is vertex flat[c]; its half-edge runs to corner following[c]
    corners = np.arange(flat.size)
    following = corners - corners % 3 + (corners + 1) % 3
    _, edge, count = np.unique(
        np.sort(np.stack([flat, flat[following]], axis=1), axis=1),
        axis=0,
        return_inverse=True,
        return_counts=True,
    )
    edge = edge.reshape(-1)
    paired = np.flatnonzero(count[edge] == 2)
    paired = paired[np.argsort(edge[paired], kind="stable")]
    first, second = [paired[0::2]], [paired[1::2]]
    crowded = np.flatnonzero(count[edge] > 2)
    crowded = crowded[np.argsort(edge[crowded], kind="stable")]
    for group in np.split(crowded, np.flatnonzero(np.diff(edge[crowded])) + 1) if len(crowded) else []:
        pairs = _radial_pairs(group, vertices, flat, following)
        first.append(pairs[:, 0])
        second.append(pairs[:, 1])
    first, second = np.concatenate(first), np.concatenate(second)
    same_way = flat[first] == flat[second]  # opposite ways where the winding is consistent
    rows = np.concatenate([first, following[first]])
    columns = np.concatenate(
        [np.where(same_way, second, following[second]), np.where(same_way, following[second], second)]
    )
    graph = coo_matrix((np.ones(len(rows)), (rows, columns)), shape=(flat.size, flat.size))
    count, fan = connected_components(graph, directed=False)
    new_vertices = np.zeros((count, 3))
    new_vertices[fan] = vertices[flat]
    return new_vertices, fan.reshape(-1, 3)


def _radial_pairs(half_edges, vertices, flat, following) -> np.ndarray:
    """(K, 2) half-edges of one edge paired so that each pair is two faces next to each other
    in angle about the edge and runs opposite ways (a closed sheet through the edge); (0, 2)
    when no such pairing exists."""
    a = vertices[flat[half_edges[0]]]
    axis = vertices[flat[following[half_edges[0]]]] - a
    axis /= np.linalg.norm(axis)
    third = half_edges - half_edges % 3 + (half_edges + 2) % 3
    spoke = vertices[flat[third]] - a
    spoke -= np.outer(spoke @ axis, axis)
    reference = spoke[0] / max(np.linalg.norm(spoke[0]), 1e-300)
    angle = np.arctan2(spoke @ np.cross(axis, reference), spoke @ reference)
    ordered = half_edges[np.argsort(angle)]
    forward = flat[ordered] == flat[half_edges[0]]
    if len(ordered) % 2 == 0:
        for shift in (0, 1):
            rolled, ways = np.roll(ordered, -shift), np.roll(forward, -shift)
            if np.all(ways[0::2] != ways[1::2]):
                return np.stack([rolled[0::2], rolled[1::2]], axis=1)
    return np.zeros((0, 2), np.int64)


def density_grid(density, lower, upper, settings: ExtractionSettings, exclude=None):
    """(values (X, Y, Z), axes): `density` sampled on the box's grid at `resolution`, blurred
    by `smoothing` voxels, zero in the box `exclude` ((2, 3) or None)."""
    axes, _ = grid_axes(lower, upper, settings.resolution)
    values = sample_density(density, axes)
    if settings.smoothing > 0:
        from scipy import ndimage

        values = ndimage.gaussian_filter(values, settings.smoothing, mode="nearest")
    if exclude is not None:
        inside = [(a >= exclude[0][i]) & (a <= exclude[1][i]) for i, a in enumerate(axes)]
        values[np.ix_(*inside)] = 0.0
    return values, axes


def mesh_from_grid(values, axes, settings: ExtractionSettings, log_level=logging.INFO):
    """The decimated surface at `threshold` of a `density_grid`."""
    vertices, faces = marching_cubes(values, axes, settings.threshold)
    mesh = keep_large_components(vertices, faces, settings.keep_fraction, log_level)
    return decimate(mesh, settings.faces, settings.keep_fraction)


def mesh_from_density(density, lower, upper, settings: ExtractionSettings, exclude=None):
    """The decimated surface of `density` inside the box (lower, upper).

    exclude : optional (2, 3) box whose density is set to zero (the object, for the environment)
    returns trimesh.Trimesh in world units
    """
    return mesh_from_grid(*density_grid(density, lower, upper, settings, exclude), settings)


# -- σ_thr from the masks ----------------------------------------------------------------------

SCORE_FACES = 1000
"""Candidate meshes are decimated to at most this many faces before their outlines are drawn
(the outline hardly changes, and drawing costs time per face)."""


@dataclasses.dataclass
class ThresholdChoice:
    """Result of `choose_threshold`: the level, each tried level's median outline IoU (None
    where it gives no surface), and the seconds the search took."""

    threshold: float
    scores: dict
    seconds: float

    def to_dict(self) -> dict:
        return {
            "threshold": self.threshold,
            "scores": {
                f"{level:g}": None if score is None else round(score, 3)
                for level, score in sorted(self.scores.items())
            },
            "seconds": round(self.seconds, 2),
        }


def choose_threshold(density, box, views, settings: ExtractionSettings) -> ThresholdChoice:
    """σ_thr from the masks: the level whose object mesh best matches them.

    Each level of `threshold` × `threshold_factors` is meshed as `extract_object` meshes the
    object (the box cut at the support found at that level, marching cubes at `resolution`,
    small parts dropped, decimated to at most SCORE_FACES), drawn into every view
    (`silhouette`) and scored by the median over the views of its outline's IoU with the mask.
    While the best is the lowest or highest level, the ladder goes on past it (at most
    `threshold_extensions` levels); then the geometric midpoints between the best level and its
    neighbours are tried. The best
    score wins; scores within `threshold_tolerance` of it are a tie, won by the level nearest
    `threshold` (in ratio). The density is sampled once per box, so a level costs a marching
    cubes, a decimation and the drawing. FignetError when no level gives a surface.

    box : (2, 3) the object's box V_o; views : the prompted or masked views (their masks set)
    """
    started = time.perf_counter()
    grids, scores = {}, {}
    faces = min(settings.faces or SCORE_FACES, SCORE_FACES)

    def score(level):
        trial = dataclasses.replace(settings, threshold=float(level), faces=faces)
        lower, upper, _ = cut_at_support(density, box, trial)
        key = (lower.tobytes(), upper.tobytes())
        if key not in grids:
            grids[key] = density_grid(density, lower, upper, trial)
        try:
            mesh = mesh_from_grid(*grids[key], trial, logging.DEBUG)
        except FignetError:
            return None
        return float(np.median(list(mask_agreement(mesh, views).values())))

    ladder = [settings.threshold * factor for factor in sorted(settings.threshold_factors)]
    for level in ladder:
        scores[level] = score(level)
    for _ in range(settings.threshold_extensions):  # the best at an end: go on past it
        best = _best_level(scores, settings)
        if best not in (ladder[0], ladder[-1]) or len(ladder) < 2:
            break
        level = ladder[0] ** 2 / ladder[1] if best == ladder[0] else ladder[-1] ** 2 / ladder[-2]
        scores[level] = score(level)
        ladder = sorted(scores)
    best = _best_level(scores, settings)
    ladder = sorted(scores)
    position = ladder.index(best)
    for neighbour in ladder[max(position - 1, 0) : position] + ladder[position + 1 : position + 2]:
        middle = float(f"{math.sqrt(best * neighbour):.3g}")  # as printed
        scores[middle] = score(middle)
    best = _best_level(scores, settings)
    seconds = time.perf_counter() - started
    log.info(
        "threshold %.4g chosen from the masks in %.1f s (median outline IoU %.3f)",
        best,
        seconds,
        scores[best],
    )
    return ThresholdChoice(best, scores, seconds)


def _best_level(scores, settings: ExtractionSettings):
    valid = {level: value for level, value in scores.items() if value is not None}
    if not valid:
        raise FignetError(
            f"no density threshold from {min(scores):.3g} to {max(scores):.3g} gives a surface in the "
            "object's box; check the prompts or the masks, or give the `threshold`"
        )
    top = max(valid.values())
    tied = [level for level, value in valid.items() if value >= top - settings.threshold_tolerance]
    return min(tied, key=lambda level: (abs(math.log(level / settings.threshold)), level))


# -- the whole extraction ----------------------------------------------------------------------


@dataclasses.dataclass
class Extraction:
    """Result of `extract_object`: meshes in world units and the boxes."""

    object_mesh: object  # trimesh.Trimesh, world coordinates
    environment_mesh: object  # trimesh.Trimesh, world coordinates
    lower: np.ndarray
    upper: np.ndarray
    origin: np.ndarray  # the object's centre of mass (its frame origin)
    passive_lower: np.ndarray
    passive_upper: np.ndarray
    support_z: float | None


def object_box_from_points(points_per_view, names, settings: ExtractionSettings):
    """Per-view 3D points of the masks -> V_o (2, 3), padded; checks the views agree."""
    boxes = [robust_box(p, settings.trim_percent) for p in points_per_view]
    check_views_agree(boxes, names, [len(p) for p in points_per_view])
    box = padded_box(robust_box(np.concatenate(points_per_view), settings.trim_percent), settings.padding)
    if not np.all(np.isfinite(box)) or not (box[1] - box[0]).max() > 0:
        raise FignetError(
            "the masks' 3D points all coincide (a box of size 0); give masks that cover the object"
        )
    return box


def cut_at_support(density, box, settings: ExtractionSettings):
    """(lower, upper, support z or None): `box` starting just above the support found under it."""
    lower, upper = np.array(box[0], np.float64), np.array(box[1], np.float64)
    _, voxel = grid_axes(lower, upper, settings.resolution)
    support = support_height(
        density,
        lower,
        upper,
        settings.threshold,
        settings.resolution,
        settings.passive_below + (upper - lower)[2],
    )
    if support is not None and support + settings.support_clearance_voxels * voxel < upper[2]:
        # The masks see the object from above: its bottom is hidden, so V_o reaches down to the
        # support (and no lower, or the support's surface would join the object).
        lower[2] = support + settings.support_clearance_voxels * voxel
    return lower, upper, support


def extract_object(
    density, box, settings: ExtractionSettings, views=(), outline_views=(), field_voxel=0.0
) -> Extraction:
    """Object and environment meshes for the object in `box` (2, 3), e.g. from
    `object_box_from_points` or a user's --box. With masked `views`, the object's density is
    carved to their visual hull first (`carve`, unless `carve_margin` is None), and to where
    fewer than `outline_votes` of the masked `outline_views` (`outline_masks`) put it outside,
    cut where `free_votes` of all of them see through it (`free_space`; by more than the
    field's `field_voxel`, about its depth's noise, too), and filled where no
    prompted view saw inside it (`hidden`, with `fill_hidden`); when the decimated mesh is not
    closed, the solid's gaps are closed (`closed`, up to `max_close_voxels`)."""
    lower, upper, support = cut_at_support(density, box, settings)
    _, voxel = grid_axes(lower, upper, settings.resolution)
    values, axes = density_grid(density, lower, upper, settings)
    if views and settings.carve_margin is not None:
        inside = carve(axes, views, settings.carve_margin)
        if settings.outline_votes > 0 and len(outline_views) >= settings.outline_votes:
            inside = np.minimum(
                inside, carve(axes, outline_views, settings.outline_margin, settings.outline_votes)
            )
        if settings.free_votes > 0:
            tolerance = max(settings.free_tolerance * float(np.max(upper - lower)), field_voxel)
            inside = inside * ~free_space(axes, [*views, *outline_views], tolerance, settings.free_votes)
        values = values * inside
        if settings.fill_hidden:
            solid = hidden(axes, views, 2 * voxel) & (inside >= 0.5)
            values = np.where(solid, np.maximum(values, 2 * settings.threshold), values)
    obj = mesh_from_grid(values, axes, settings)
    voxels = 0
    while not obj.is_watertight and voxels < settings.max_close_voxels:
        voxels += 1
        obj = mesh_from_grid(closed(values, settings.threshold, voxels), axes, settings, logging.DEBUG)
    if voxels:
        log.info(
            "gaps of up to %d voxels in the object's solid closed: its mesh is %s",
            2 * voxels,
            "closed" if obj.is_watertight else "still not closed",
        )
    passive_lower, passive_upper = passive_box(lower, upper, support, settings)
    exclude = np.stack([lower - [0, 0, 0.5 * voxel], upper + voxel])
    try:
        environment = mesh_from_density(density, passive_lower, passive_upper, settings, exclude=exclude)
    except FignetError:
        if support is None:
            raise
        environment = None  # only a faint support, which the plane below stands for
    tolerance = 2 * max(voxel, grid_axes(passive_lower, passive_upper, settings.resolution)[1])
    environment = with_support_plane(
        environment, lower, upper, passive_lower, passive_upper, support, tolerance
    )
    origin = np.asarray(obj.center_mass if obj.is_watertight else obj.bounds.mean(axis=0), np.float64)
    return Extraction(obj, environment, lower, upper, origin, passive_lower, passive_upper, support)


def with_support_plane(environment, lower, upper, passive_lower, passive_upper, support, tolerance):
    """The environment mesh, plus a flat rectangle at the support height over the passive box's
    footprint when the mesh has no surface there under the object.

    A support the field holds only faintly (a shiny tray floor: density peaks below the
    marching-cubes threshold) is found by `support_height` but gives no faces, and a dropped
    object would fall through it. Vertical rays on a ring around V_o's footprint (halfway to the
    passive box's edge) test whether the mesh has a face within `tolerance` of the support; if
    under half do, the plane is added.
    """
    import trimesh

    if support is None:
        return environment
    if environment is not None:
        ring = _footprint_ring(
            0.5 * (lower[:2] + passive_lower[:2]), 0.5 * (upper[:2] + passive_upper[:2]), 8
        )
        origins = np.column_stack([ring, np.full(len(ring), upper[2] + 1.0)])
        hits, rays, _ = environment.ray.intersects_location(
            origins, np.tile([0.0, 0.0, -1.0], (len(origins), 1))
        )
        near = np.abs(hits[:, 2] - support) <= tolerance
        if len(np.unique(rays[near])) >= 0.5 * len(origins):
            return environment
    (x0, y0), (x1, y1) = passive_lower[:2], passive_upper[:2]
    plane = trimesh.Trimesh(
        [[x0, y0, support], [x1, y0, support], [x1, y1, support], [x0, y1, support]],
        [[0, 1, 2], [0, 2, 3]],
        process=False,
    )
    return plane if environment is None else trimesh.util.concatenate([environment, plane])


def passive_box(lower, upper, support, settings: ExtractionSettings):
    """The environment's box: V_o's footprint grown by passive_margin, from passive_below under
    the support surface (V_o's bottom where none was found) to passive_above over it."""
    base = lower[2] if support is None else support
    above = (upper - lower)[2] if settings.passive_above is None else settings.passive_above
    margin = settings.passive_margin
    passive_lower = np.array([lower[0] - margin, lower[1] - margin, base - settings.passive_below])
    passive_upper = np.array([upper[0] + margin, upper[1] + margin, base + max(above, 1e-6)])
    return passive_lower, passive_upper


# -- views, prompts and files ------------------------------------------------------------------


@dataclasses.dataclass
class View:
    """One prompted or masked view: what segmentation and unprojection need.

    depth : (H, W) z-depth; opacity : (H, W) or None; image : (H, W, 3) uint8 RGB or None
    prompts : list of (u, v) pixels on the object; mask : (H, W) bool or None (given by the user)
    surface : (H, W) z-depth of the first surface (a NeRF's median depth: where a ray has lost
    half its light; 0: unknown) or None, for `free_space`
    """

    name: str
    K: np.ndarray
    c2w: np.ndarray
    depth: np.ndarray
    opacity: np.ndarray | None = None
    image: np.ndarray | None = None
    prompts: list = dataclasses.field(default_factory=list)
    mask: np.ndarray | None = None
    surface: np.ndarray | None = None


def view_masks(views, segmentation_settings=None):
    """Fill each view's mask from its prompts (union over the view's prompts); returns views."""
    from fignetctl.core.segmentation import SegmentationSettings, check_prompt, prompt_mask

    settings = segmentation_settings or SegmentationSettings()
    for view in views:
        if view.mask is not None:
            continue
        height, width = view.depth.shape
        mask = np.zeros((height, width), bool)
        for u, v in view.prompts:
            check_prompt(
                u, v, width, height, view.depth, view.opacity, settings, where=f"prompt {view.name}:{u},{v}"
            )
            mask |= prompt_mask(view.image, view.depth, view.K, u, v, settings)
        view.mask = mask
    return views


def object_box_from_views(views, settings: ExtractionSettings):
    """V_o (2, 3) from the masked views (unprojected with their depth, trimmed, padded)."""
    points, names = [], []
    for view in views:
        mask = view.mask if view.opacity is None else view.mask & (view.opacity >= 0.5)
        if not mask.any():
            raise FignetError(f"the mask of {view.name} is empty (or covers only empty space)")
        points.append(masked_points(view.depth, mask, view.K, view.c2w))
        names.append(view.name)
    return object_box_from_points(points, names, settings)


def hull_grid(density, box, settings: ExtractionSettings):
    """(axes, voxel, points (N, 3), σ (X, Y, Z)) of `box` at `hull_resolution`."""
    axes, voxel = grid_axes(box[0], box[1], settings.hull_resolution)
    return axes, voxel, grid_points(axes), sample_density(density, axes)


def consistent_box(density, views, settings: ExtractionSettings):
    """V_o from the views' masks, the masks made to agree: their visual hull (`hull_box`) sought
    in the masks' box (`object_box_from_views`) grown by `hull_reach` but not downwards, the masks
    redrawn from it (`hull_masks`), and the hull taken again with the new masks. The views'
    masks are replaced."""
    coarse = object_box_from_views(views, settings)
    if settings.hull_resolution <= 0 or len(views) < 2:
        return coarse
    search = padded_box(coarse, settings.hull_reach)
    search[0][2] = coarse[0][2]  # not downwards: under the object is the support
    resolution = round(
        settings.hull_resolution * (search[1] - search[0]).max() / (coarse[1] - coarse[0]).max()
    )
    grid = hull_grid(density, search, dataclasses.replace(settings, hull_resolution=resolution))
    box, level = hull_box(density, search, views, settings, grid)
    hull_masks(density, box, views, dataclasses.replace(settings, threshold=level))
    return hull_box(density, search, views, settings, grid)[0]


HULL_LEVELS = 4
"""`hull_box` tries the threshold and up to this many levels in all, each half the one before."""

HULL_WHOLE = 0.5
"""... and takes the first whose largest connected part holds at least this fraction of the
voxels that pass (the object in one piece)."""


def hull_box(density, box, views, settings: ExtractionSettings, grid=None):
    """(V_o refined by all the masks at once (a visual hull), the density level it was taken at).

    Per-view masks err differently: one takes in a piece of the container's wall, another
    misses a rim. In `box`, the voxels whose density is above the level and that
    project inside every view's mask (grown by `hull_dilation` pixels) hold the object and
    little else; their largest connected part, padded and clipped to `box`, is V_o. Occluded
    space (behind or under the object) passes the test too, which is why the unseen bottom is
    later cut at the support, and why the result is never wider than `box`.

    The level is the threshold unless the voxels above it fall apart, as a field that holds
    the object only as a thin, patchy shell gives: then it is halved (`HULL_LEVELS`,
    `HULL_WHOLE`) until the largest part holds most of them. Taken at the threshold, that part
    would be a piece of the object (a cap), V_o too small, and the support search beside it
    would meet the object's own sides. Returns (`box`, threshold) unchanged when no voxel
    passes (or `hull_resolution` is 0).

    grid : `hull_grid(density, box, settings)` when already sampled
    """
    from scipy import ndimage

    if settings.hull_resolution <= 0 or len(views) < 2:
        return box, settings.threshold
    axes, voxel, points, values = grid if grid is not None else hull_grid(density, box, settings)
    in_masks = _inside_every_mask(points, views, settings).reshape(values.shape)
    best = None
    for level in settings.threshold / 2.0 ** np.arange(HULL_LEVELS):
        inside = in_masks & (values > level)
        labels, count = ndimage.label(inside)
        if count == 0:
            continue
        sizes = ndimage.sum(inside, labels, index=np.arange(1, count + 1))
        whole = sizes.max() / sizes.sum()
        if best is None or whole > best[0]:
            best = (whole, level, labels == 1 + int(np.argmax(sizes)), count)
        if whole >= HULL_WHOLE:
            break
    if best is None:
        log.warning("no voxel of the masks' box projects into every mask; keeping the masks' box")
        return box, settings.threshold
    whole, level, part, count = best
    if level != settings.threshold:
        log.info(
            "the object's voxels above density %g fall apart; its box is taken at %g (%d pieces, the "
            "largest %.0f %%)",
            settings.threshold,
            level,
            count,
            100 * whole,
        )
    cells = np.argwhere(part)
    lower = np.array([axes[i][cells[:, i].min()] for i in range(3)]) - voxel
    upper = np.array([axes[i][cells[:, i].max()] for i in range(3)]) + voxel
    hull = padded_box(np.stack([lower, upper]), settings.padding)
    # the hull only ever shrinks V_o
    return np.stack([np.maximum(hull[0], box[0]), np.minimum(hull[1], box[1])]), level


HOLE_FRACTION = 0.02
"""Holes of a redrawn mask up to this fraction of its area are GrabCut's specks and are filled;
larger ones are openings through the object (a mug's handle) and stay."""


def hull_masks(density, box, views, settings: ExtractionSettings):
    """Redraw each prompted view's mask from the object in 3D, so every view agrees.

    The voxels of the object's box (`hull_box`, cut `hull_mask_clearance` above the support)
    with density above the threshold (`hull_box`'s level) that project inside every mask are
    splatted into each view; GrabCut then settles the edge from colour, with the splat as
    probable foreground, its core (where the old mask agreed) as certain foreground and a ring
    around it as probable background. Views without an image
    or without prompts (masks the user gave) keep their masks. Returns the views.
    """
    import cv2

    from fignetctl.core.segmentation import fill_holes, grabcut

    lower, upper, support = cut_at_support(density, box, settings)
    if support is not None:
        lower[2] = max(lower[2], support + settings.hull_mask_clearance * (upper[2] - support))
    _, _, points, values = hull_grid(density, np.stack([lower, upper]), settings)
    points = points[values.reshape(-1) > settings.threshold]
    points = points[_inside_every_mask(points, views, settings)]
    if len(points) == 0:
        return views
    reach = settings.hull_mask_reach * float(np.max(upper - lower))
    for view in views:
        if view.image is None or not view.prompts:
            continue
        splat = _splat(points, view, view.mask.shape)
        labels, _ = _trimap(splat, settings.hull_mask_margin)
        labels[_far_from(points, view, labels == cv2.GC_PR_BGD, reach)] = cv2.GC_BGD
        labels[cv2.erode(splat.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool) & view.mask] = (
            cv2.GC_FGD
        )
        if not (labels == cv2.GC_FGD).any():
            continue
        view.mask = fill_holes(grabcut(view.image, labels, 5), HOLE_FRACTION)
    return views


def _trimap(splat, ring_fraction):
    """(GrabCut labels (H, W) uint8, ring width px) around a splat of an object (H, W) bool:
    the splat probable foreground, a ring around it as wide as `ring_fraction` of its size
    (√area, at least 2 px) probable background, the rest background."""
    import cv2

    margin = max(2, int(np.rint(ring_fraction * np.sqrt(splat.sum()))))
    ring = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1,) * 2)
    labels = np.full(splat.shape, cv2.GC_BGD, np.uint8)
    labels[cv2.dilate(splat.astype(np.uint8), ring).astype(bool)] = cv2.GC_PR_BGD
    labels[splat] = cv2.GC_PR_FGD
    return labels, margin


def _far_from(points, view, candidates, reach, samples=24):
    """(H, W) bool: the `candidates` pixels whose ray passes further than `reach` from every one
    of `points` (P, 3) on its way to the surface the view's depth holds (sampled at `samples`
    z-depths over the points' own z-range in the view, grown by `reach`). A ray through the
    object's faint lower part (where the depth lands on the support behind it) passes near its
    voxels; one onto the support beside the object does not."""
    from scipy.spatial import cKDTree

    far = np.zeros(candidates.shape, bool)
    rows, columns = np.nonzero(candidates & (view.depth > 0))
    if len(rows) == 0:
        return far
    depths = pinhole.project(view.K, view.c2w, points)[1]
    near_z, far_z = depths.min() - reach, depths.max() + reach
    surface = view.depth[rows, columns]
    steps = np.linspace(0.0, 1.0, samples)
    z = near_z + (np.minimum(surface, far_z) - near_z)[:, None] * steps  # (R, samples)
    z = np.maximum(z, 1e-6)
    along = pinhole.unproject(
        view.K, view.c2w, np.repeat(columns, samples), np.repeat(rows, samples), z.reshape(-1)
    )
    distance = cKDTree(points).query(along, distance_upper_bound=reach)[0].reshape(len(rows), samples)
    far[rows, columns] = distance.min(axis=1) > reach
    return far


def carve(axes, views, margin, votes=1) -> np.ndarray:
    """(X, Y, Z) factors in [0, 1] on the grid of `axes`: 1 where a grid point projects inside
    every view's mask (or within `margin` pixels of it), 0 where it projects further than
    margin + 0.5 px outside one, a linear ramp between (so the surface of density × factor
    keeps sub-pixel positions). Views a point projects outside of (or lies behind) do not
    constrain it. With `votes` > 1 a point is cut only as far as the `votes`-th view against
    it cuts it (masks that each err somewhere cut only where several agree).

    A visual hull: the NeRF's density around an object holds a halo and pieces of what touches
    it (the tray's rim, a shadow), which marching cubes would add to the mesh; the masks say
    where the object is not. Space that every view sees only through the object (its unseen
    bottom, its concavities) is not carved."""
    import cv2
    from scipy import ndimage

    shape = tuple(len(a) for a in axes)
    points = grid_points(axes)
    lowest = np.ones((max(int(votes), 1), len(points)), np.float32)  # each point's smallest factors
    for view in views:
        mask = np.asarray(view.mask, bool)
        outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
        inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
        beyond = np.where(mask, 0.5 - inside, outside - 0.5)  # px past the mask's edge
        image, depth = pinhole.project(view.K, view.c2w, points)
        u, v = (image - pinhole.PIXEL_CENTRE).T
        height, width = mask.shape
        seen = (depth > 1e-9) & (u >= -0.5) & (u <= width - 0.5) & (v >= -0.5) & (v <= height - 0.5)
        distance = ndimage.map_coordinates(beyond, [v[seen], u[seen]], order=1, mode="nearest")
        factor = np.ones(len(points), np.float32)
        factor[seen] = np.clip(margin + 0.5 - distance, 0.0, 1.0)
        for row in lowest:  # insert into the sorted rows, the largest falling out
            row[:], factor = np.minimum(row, factor), np.maximum(row, factor)
    return lowest[-1].reshape(shape)


def outline_masks(mesh, views, box, settings: ExtractionSettings) -> list:
    """Masks for views nobody prompted, drawn around the object mesh's outline: for each view
    (with its image, and its depth where the outline and a ring around it fall) whose outline
    of the world `mesh` lies inside the image and is not covered by anything nearer than the
    object's `box` (2, 3) by 5 % of its longest side (at most `outline_occluded` of it),
    GrabCut settles the edge from colour, with the outline as probable foreground, its core as
    certain foreground and a ring as probable background. A mask is kept when it overlaps the
    outline by `outline_min_iou`. Returns copies of the views kept, with their masks."""
    import cv2

    from fignetctl.core.segmentation import fill_holes, grabcut, iou

    corners = np.array(np.meshgrid(*np.asarray(box, np.float64).T, indexing="ij")).reshape(3, -1).T
    tolerance = 0.05 * float(np.max(np.asarray(box)[1] - np.asarray(box)[0]))
    kept = []
    for view in views:
        shape = view.image.shape[:2]
        drawn = silhouette(mesh.vertices, mesh.faces, view, shape)
        if None in bounding_extent(drawn) or drawn.sum() < OUTLINE_PIXELS:
            continue
        near = pinhole.project(view.K, view.c2w, corners)[1].min()
        depth = view.depth[drawn]
        if near <= 0 or np.mean((depth > 0) & (depth < near - tolerance)) > settings.outline_occluded:
            continue
        labels, margin = _trimap(drawn, settings.hull_mask_margin)
        inner = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * (margin // 2) + 1,) * 2)
        labels[cv2.erode(drawn.astype(np.uint8), inner).astype(bool)] = cv2.GC_FGD
        if not (labels == cv2.GC_FGD).any():
            continue
        rows, columns = np.nonzero(labels != cv2.GC_BGD)
        window = np.s_[
            max(rows.min() - margin, 0) : rows.max() + margin + 1,
            max(columns.min() - margin, 0) : columns.max() + margin + 1,
        ]
        mask = np.zeros(shape, bool)
        mask[window] = fill_holes(grabcut(view.image[window], labels[window], 5), HOLE_FRACTION)
        if iou(mask, drawn) >= settings.outline_min_iou:
            kept.append(dataclasses.replace(view, mask=mask, prompts=[]))
    return kept


OUTLINE_PIXELS = 64
"""`outline_masks` passes over views where the object's outline covers fewer pixels."""


def free_space(axes, views, tolerance, votes, erosion=2) -> np.ndarray:
    """(X, Y, Z) bool on the grid of `axes`: points more than `tolerance` in front of the first
    surface (`View.surface`) in at least `votes` of the `views`, counted only at pixels inside
    the view's mask shrunk by `erosion` px (at a mask's edge the surface may be what lies
    behind the object). Space a view sees through to a surface behind it is empty."""
    import cv2

    shape = tuple(len(a) for a in axes)
    points = grid_points(axes)
    count = np.zeros(len(points), np.int32)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erosion + 1,) * 2)
    for view in views:
        if view.surface is None or view.mask is None:
            continue
        core = cv2.erode(np.asarray(view.mask, np.uint8), kernel).astype(bool) & (view.surface > 0)
        u, v, keep, depth = _pixels(points, view, core.shape)
        keep[keep] = core[v[keep], u[keep]]
        count[keep] += depth[keep] < view.surface[v[keep], u[keep]] - tolerance
    return (count >= votes).reshape(shape)


def hidden(axes, views, tolerance) -> np.ndarray:
    """(X, Y, Z) bool on the grid of `axes`: points that lie more than `tolerance` behind the
    surface (the view's z-depth at their pixel) in every view they project into, and into at
    least one; a pixel without depth (0) sees through, so its points are not hidden."""
    shape = tuple(len(a) for a in axes)
    points = grid_points(axes)
    behind = np.ones(len(points), bool)
    seen_by = np.zeros(len(points), bool)
    for view in views:
        u, v, keep, depth = _pixels(points, view, view.depth.shape)
        surface = np.zeros(len(points))
        surface[keep] = view.depth[v[keep], u[keep]]
        behind[keep] &= (surface[keep] > 0) & (depth[keep] > surface[keep] + tolerance)
        seen_by |= keep
    return (behind & seen_by).reshape(shape)


def _inside_every_mask(points, views, settings: ExtractionSettings):
    """(P,) bool: points that project inside every view's mask, each grown by `hull_dilation` px."""
    import cv2

    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * settings.hull_dilation + 1,) * 2)
    inside = np.ones(len(points), bool)
    for view in views:
        inside &= _projects_into(points, cv2.dilate(view.mask.astype(np.uint8), kernel).astype(bool), view)
    return inside


def _splat(points, view, shape):
    """(H, W) bool: the pixels the points fall on, closed (5 px) and with holes filled."""
    import cv2

    from fignetctl.core.segmentation import fill_holes

    u, v, keep, _ = _pixels(points, view, shape)
    splat = np.zeros(shape, np.uint8)
    splat[v[keep], u[keep]] = 1
    return fill_holes(cv2.morphologyEx(splat, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)).astype(bool))


def _projects_into(points, mask, view):
    """(P,) bool: world points in front of the view's camera whose pixel is set in `mask`."""
    u, v, keep, _ = _pixels(points, view, mask.shape)
    result = np.zeros(len(points), bool)
    result[keep] = mask[v[keep], u[keep]]
    return result


def _pixels(points, view, shape):
    """The pixel (u, v) of each world point in the view, whether it is in front of the camera
    and inside an image of `shape` (H, W), and its z-depth."""
    image, depth = pinhole.project(view.K, view.c2w, points)
    u, v = pinhole.pixel_of(image).T
    return u, v, (depth > 1e-9) & (u >= 0) & (u < shape[1]) & (v >= 0) & (v < shape[0]), depth


def silhouette(vertices, faces, view, shape) -> np.ndarray:
    """(H, W) bool: the pixels whose centre a mesh (world vertices (V, 3), triangles (F, 3))
    covers in the view; triangles with a corner behind the camera are left out. Most triangles
    (those whose pixel box is no wider than 95 % of them, at most 32 px) are drawn in batches,
    the others one by one."""
    image, depth = pinhole.project(view.K, view.c2w, vertices)
    faces = np.asarray(faces)
    triangles = image[faces[(depth[faces] > 1e-9).all(axis=1)]]
    low = np.maximum(np.floor(triangles.min(1) - pinhole.PIXEL_CENTRE), 0).astype(int)
    high = np.minimum(np.ceil(triangles.max(1) - pinhole.PIXEL_CENTRE), [shape[1] - 1, shape[0] - 1]).astype(
        int
    )
    drawn = np.all(high >= low, axis=1)
    widths = (high - low).max(axis=1) + 1
    tile = int(np.clip(np.percentile(widths[drawn], 95), 1, 32)) if drawn.any() else 1
    small = drawn & (widths <= tile)
    covered = np.zeros(shape, bool)
    steps, chunk = np.arange(tile), max(2**20 // tile**2, 1)
    for start in range(0, int(small.sum()), chunk):
        part = slice(start, start + chunk)
        corners, first, last = triangles[small][part], low[small][part], high[small][part]
        u = (first[:, 0, None, None] + steps[None, None, :]).repeat(tile, 1)
        v = (first[:, 1, None, None] + steps[None, :, None]).repeat(tile, 2)
        inside = _covers(corners[:, None, None], u + pinhole.PIXEL_CENTRE, v + pinhole.PIXEL_CENTRE)
        inside &= (u <= last[:, 0, None, None]) & (v <= last[:, 1, None, None])
        covered[v[inside], u[inside]] = True
    for triangle, first, last in zip(triangles[drawn & ~small], low[drawn & ~small], high[drawn & ~small]):
        v, u = np.mgrid[first[1] : last[1] + 1, first[0] : last[0] + 1] + pinhole.PIXEL_CENTRE
        covered[first[1] : last[1] + 1, first[0] : last[0] + 1] |= _covers(triangle, u, v)
    return covered


def _covers(triangle, u, v):
    """Whether the points (u, v) lie in the triangle (..., 3, 2) (edges included, either winding)."""
    sides = [
        (b[..., 0] - a[..., 0]) * (v - a[..., 1]) - (b[..., 1] - a[..., 1]) * (u - a[..., 0])
        for a, b in (
            (triangle[..., 0, :], triangle[..., 1, :]),
            (triangle[..., 1, :], triangle[..., 2, :]),
            (triangle[..., 2, :], triangle[..., 0, :]),
        )
    ]
    return ((sides[0] >= 0) & (sides[1] >= 0) & (sides[2] >= 0)) | (
        (sides[0] <= 0) & (sides[1] <= 0) & (sides[2] <= 0)
    )


def mask_agreement(mesh, views) -> dict:
    """{view name: IoU of the mesh's outline (world mesh) and the view's mask}."""
    from fignetctl.core.segmentation import iou

    return {
        view.name: iou(silhouette(mesh.vertices, mesh.faces, view, view.mask.shape), view.mask)
        for view in views
    }


def bounding_extent(mask):
    """(width, height) in pixels of a mask's bounding box, each None when the mask touches the
    image's left/right (top/bottom) border (the object may go on past it) or is empty."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return None, None
    columns, rows = np.flatnonzero(mask.any(axis=0)), np.flatnonzero(mask.any(axis=1))
    width = None if columns[0] == 0 or columns[-1] == mask.shape[1] - 1 else int(columns[-1] - columns[0] + 1)
    height = None if rows[0] == 0 or rows[-1] == mask.shape[0] - 1 else int(rows[-1] - rows[0] + 1)
    return width, height


def outline_extents(mesh, views) -> dict:
    """{view name: {"width": [mesh px, mask px], "height": [...]}}: the bounding boxes of the mesh's
    outline (`silhouette`) and of the view's mask; an axis is left out where either touches the
    image border."""
    result = {}
    for view in views:
        drawn = bounding_extent(silhouette(mesh.vertices, mesh.faces, view, view.mask.shape))
        masked = bounding_extent(view.mask)
        result[view.name] = {
            axis: [drawn[i], masked[i]]
            for i, axis in enumerate(("width", "height"))
            if drawn[i] is not None and masked[i] is not None
        }
    return result


FINER_FIELD = "fit a finer NeRF around the objects (fit-nerf's `region=prompts`)"
"""The advice for a field too coarse for the object, when it was fitted without a region."""


def check_outline_extents(
    extents: dict, settings: ExtractionSettings, finer: str | None = FINER_FIELD
) -> list:
    """Compare the mesh's outline with the masks per view and image axis (`outline_extents`).
    FignetError when the median view's worst axis is off by more than max_extent; else a
    warning line (returned and logged) for each view and axis off by more than warn_extent.
    `finer`, how to get a finer field, is advised too (None: the field is fine enough)."""
    worst = {}
    for name, axes in extents.items():
        errors = {axis: drawn / masked - 1.0 for axis, (drawn, masked) in axes.items() if masked > 0}
        if errors:
            worst[name] = max(errors.items(), key=lambda item: abs(item[1]))
    if not worst:
        return []
    median = float(np.median([abs(error) for _, error in worst.values()]))
    advice = (
        (f"{finer}, " if finer else "")
        + f"add prompted views, or set `threshold` (now {settings.threshold:g}; lower grows the mesh, "
        "higher shrinks it)"
    )
    if median > settings.max_extent:
        name = max(worst, key=lambda key: abs(worst[key][1]))
        axis, error = worst[name]
        raise FignetError(
            f"the mesh's size does not match the masks: its outline's {axis} is {100 * error:+.0f} % off "
            f"the mask's in {name} and over {100 * settings.max_extent:.0f} % in the median view; {advice}"
        )
    warnings = []
    for name, axes in extents.items():
        for axis, (drawn, masked) in axes.items():
            error = drawn / masked - 1.0 if masked > 0 else 0.0
            if abs(error) > settings.warn_extent:
                sense = {"width": ("wider", "narrower"), "height": ("taller", "shorter")}[axis]
                warnings.append(
                    f"{name}: the mesh's outline is {100 * abs(error):.0f} % {sense[error < 0]} than the mask "
                    f"({drawn} px vs {masked} px, image {axis}), so the mesh is about that much too "
                    f"{'large' if error > 0 else 'small'} along that direction; {advice}"
                )
    for line in warnings:
        log.warning("%s", line)
    return warnings


def check_mask_agreement(agreement: dict, settings: ExtractionSettings) -> None:
    """FignetError when the median view's IoU is below min_mask_iou; a warning naming each view
    below warn_mask_iou."""
    if not agreement:
        return
    median = float(np.median(list(agreement.values())))
    worst = min(agreement, key=agreement.get)
    if median < settings.min_mask_iou:
        raise FignetError(
            f"the mesh does not match the masks (outline IoU {median:.2f} in the median view, "
            f"{agreement[worst]:.2f} in {worst}; at least {settings.min_mask_iou} needed): the density threshold "
            f"({settings.threshold:g}{', the best of those tried' if settings.auto_threshold else ''}) may cut "
            "the object apart or merge it with its surroundings, or the "
            "prompts may sit on different objects; look at the masks and change one or the other"
        )
    for name, value in agreement.items():
        if value < settings.warn_mask_iou:
            log.warning(
                "%s: the mesh's outline and the mask overlap little (IoU %.2f); check the mesh there",
                name,
                value,
            )
