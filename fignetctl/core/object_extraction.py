"""`extract-mesh`'s library side, objects in and out: prompts given as text -> views, views
(prompts or masks, depth) or a box -> the object's and environment's meshes with the outline
checks. The geometry is in `mesh_extraction`, the masks in `segmentation`; reading the inputs
and writing object.obj, environment.obj, volume.npz and masks/ is the stage's
(`fignetctl.stages.extract_mesh`)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from fignetctl.core.mesh_extraction import (
    FINER_FIELD,
    Extraction,
    ExtractionSettings,
    View,
    check_mask_agreement,
    check_outline_extents,
    choose_threshold,
    consistent_box,
    extract_object,
    mask_agreement,
    outline_extents,
    outline_masks,
    padded_box,
    silhouette,
    view_masks,
)
from fignetctl.errors import FignetError, FormatError

log = logging.getLogger(__name__)


@dataclasses.dataclass
class ObjectExtraction:
    """What `extract` made: the meshes and boxes, the settings with σ_thr as it was set, the
    views with their masks (none for a box), and the outline checks (mask_iou per view,
    watertight, threshold, threshold_choice)."""

    extraction: Extraction
    settings: ExtractionSettings
    views: list
    checks: dict


def extract(
    density,
    settings: ExtractionSettings,
    views=(),
    box=None,
    segmentation=None,
    voxel=None,
    more_views=None,
    region=None,
) -> ObjectExtraction:
    """The object given by `views` (View, with prompts or masks; masks are made from prompts by
    `segmentation`) or by `box` (x0, y0, z0, x1, y1, z1), meshed from `density` with its
    environment. `more_views(mesh)`, when given, returns the views nobody prompted (View with
    image and depth around the world `mesh`'s outline, `unprompted_views`): their masks, drawn
    around the first mesh's outline (`outline_masks`), carve the object again (`outline_votes`).
    The mesh's outline is checked against the prompted views' masks (`check_mask_agreement`: IoU,
    `check_outline_extents`: width and height per view), and warnings are logged (and listed in
    checks["warnings"]) for an outline off the masks, a mesh that is not watertight, and a field
    whose finest `voxel` (world units, when known) is coarse for the object's size, with advice
    on a finer one (`finer_field`; `region`: the field's fine region (2, 3), if it has one)."""
    if box is not None:
        box = np.array(box, np.float64).reshape(2, 3)
        if np.any(box[1] <= box[0]):
            raise FignetError("`box`: x1, y1, z1 must be greater than x0, y0, z0")
        views = []
    else:
        views = view_masks(list(views), segmentation)
        box = consistent_box(density, views, settings)
    settings, threshold = _threshold(density, box, views, settings)
    extraction = extract_object(density, box, settings, views, field_voxel=voxel or 0.0)
    outline = {}
    if views and more_views is not None and settings.carve_margin is not None and settings.outline_votes > 0:
        candidates = more_views(extraction.object_mesh)
        extracted_box = np.stack([extraction.lower, extraction.upper])
        masked = outline_masks(extraction.object_mesh, candidates, extracted_box, settings)
        outline = {"candidates": len(candidates), "used": [view.name for view in masked]}
        if len(masked) >= settings.outline_votes:
            extraction = extract_object(density, box, settings, views, masked, voxel or 0.0)
        log.info(
            "%d of %d views nobody prompted have a clear mask of the object%s",
            len(masked),
            len(candidates),
            f"; where {settings.outline_votes} of them agree, they carve it too"
            if len(masked) >= settings.outline_votes
            else f" (under {settings.outline_votes}): only the prompted views carve it",
        )
    agreement = {
        name: round(value, 3) for name, value in mask_agreement(extraction.object_mesh, views).items()
    }
    check_mask_agreement(agreement, settings)
    extents = outline_extents(extraction.object_mesh, views)
    finer = finer_field(extraction, region)
    coarse = voxel is None or voxel > settings.warn_voxel * _smallest_side(extraction.object_mesh)
    warnings = check_outline_extents(extents, settings, finer if coarse else None)
    warnings += _mesh_warnings(extraction.object_mesh, settings, voxel, finer)
    checks = {
        "mask_iou": agreement,
        "outline_extent_px": extents,
        "warnings": warnings,
        "watertight": bool(extraction.object_mesh.is_watertight),
        "threshold": settings.threshold,
        "threshold_choice": threshold,
        "outline_views": outline,
    }
    return ObjectExtraction(extraction, settings, views, checks)


def unprompted_views(cameras, model, read_image, skip=()):
    """`extract`'s `more_views`: a function of the world mesh giving a View of every camera
    not in `skip` (indices) that the mesh's outline falls in, with its image (`read_image(index)`,
    RGB uint8) and the NeRF `model`'s depth rendered around the outline (0 elsewhere)."""
    import cv2

    def views(mesh):
        result = []
        shape = (int(cameras.height), int(cameras.width))
        for index in range(len(cameras)):
            if index in skip:
                continue
            view = View(
                str(cameras.image_names[index]), cameras.K[index], cameras.c2w[index], np.zeros(shape)
            )
            drawn = silhouette(mesh.vertices, mesh.faces, view, shape)
            if not drawn.any():
                continue
            margin = max(2, int(np.rint(0.5 * np.sqrt(drawn.sum()))))
            near = cv2.dilate(drawn.astype(np.uint8), np.ones((2 * margin + 1,) * 2, np.uint8)).astype(bool)
            rendering = model.render(cameras, index, pixels=near)
            view.depth = np.where(rendering.opacity > 0.5, rendering.median_depth, 0.0)
            view.surface = view.depth
            view.image = read_image(index)
            result.append(view)
        return result

    return views


def finer_field(extraction: Extraction, region=None) -> str:
    """How to get a field fine enough for the extracted object: a region around the objects, or,
    for a field that has one (`region`), a region around this object alone (V_o grown by half
    its longest side each way): the region's grid keeps its vertex count, so a smaller region
    has finer voxels."""
    if region is None:
        return FINER_FIELD
    box = padded_box(np.stack([extraction.lower, extraction.upper]), 0.5)
    return (
        "fit the NeRF's fine region around this object alone, where its voxels are finer "
        f"(fit-nerf's `region={','.join(f'{value:.3f}' for value in box.reshape(-1))}`)"
    )


def _mesh_warnings(mesh, settings: ExtractionSettings, voxel=None, finer=FINER_FIELD) -> list:
    """Warning lines (also logged) for an object mesh that is not watertight and for a field
    whose finest `voxel` is over `warn_voxel` of the mesh's smallest side; FignetError when the
    voxel is over `max_voxel` of it. `finer`: how to get a finer field (`finer_field`)."""
    warnings = []
    if not mesh.is_watertight:
        warnings.append(
            "the object mesh is not watertight (it has open edges): its volume, centre of mass and "
            "inertia are not defined and the simulation needs a closed mesh; try more `faces` "
            "(decimation can open it) or another `threshold`"
        )
    smallest = _smallest_side(mesh)
    if voxel is not None and smallest > 0 and voxel > settings.max_voxel * smallest:
        raise FignetError(
            f"the NeRF's finest voxel ({voxel:.3g} world units) is {100 * voxel / smallest:.0f} % of the "
            f"object mesh's smallest side ({smallest:.3g}): the object is under {1 / settings.max_voxel:.0f} voxels "
            f"across, and a side can be off by a voxel; {finer}, or accept a coarse mesh "
            f"with `max_voxel` above {voxel / smallest:.2f}"
        )
    if voxel is not None and smallest > 0 and voxel > settings.warn_voxel * smallest:
        warnings.append(
            f"the NeRF's finest voxel ({voxel:.3g} world units) is {100 * voxel / smallest:.0f} % of the "
            f"object's smallest side ({smallest:.3g}), so its size is uncertain by up to a voxel; {finer}"
        )
    for line in warnings:
        log.warning("%s", line)
    return warnings


def _smallest_side(mesh) -> float:
    return float(np.min(mesh.extents)) if len(mesh.vertices) else 0.0


def _threshold(density, box, views, settings: ExtractionSettings):
    """(settings with σ_thr set, how it was set): chosen from the masks when `auto_threshold`
    and there are masks (`choose_threshold`), else `threshold` as it is."""
    if not settings.auto_threshold:
        return settings, {"source": "given"}
    if not views:
        log.info("no masks to choose the threshold from: using %g", settings.threshold)
        return settings, {"source": "default (no masks to choose it from)"}
    choice = choose_threshold(density, box, views, settings)
    search = {key: value for key, value in choice.to_dict().items() if key != "threshold"}
    return dataclasses.replace(settings, threshold=choice.threshold), {"source": "masks", **search}


def prompted_view(index, cameras, model, depth_images=None, image=None) -> View:
    """View `index` of `cameras` (its RGB `image` (H, W, 3) uint8 or None): its depth from
    `depth_images` (N, H, W) when given, else rendered by the NeRF `model` (with its opacity)."""
    name = str(cameras.image_names[index])
    if depth_images is not None:
        return View(name, cameras.K[index], cameras.c2w[index], depth_images[index], None, image)
    rendering = model.render(cameras, index)
    depth = np.where(rendering.opacity > 0.5, rendering.depth, 0.0)
    surface = np.where(rendering.opacity > 0.5, rendering.median_depth, 0.0)
    return View(name, cameras.K[index], cameras.c2w[index], depth, rendering.opacity, image, surface=surface)


def view_index(text, cameras) -> int:
    """A view given as an image name (or file name) or a 0-based index."""
    text = text.strip()
    if text.isdecimal() and text.isascii():  # "²" is a digit to isdigit() but not to int()
        index = int(text)
        if index >= len(cameras):
            raise FignetError(f"view index {index} is out of range (the cameras have {len(cameras)} views)")
        return index
    try:
        return cameras.index_of(text)
    except FormatError as error:
        raise FignetError(str(error)) from None


def parse_prompts(texts, cameras) -> dict:
    """["VIEW:U,V", ...] -> {view index: [(u, v), ...]}."""
    prompts = {}
    for text in texts:
        view, _, pixel = text.rpartition(":")
        try:
            u, v = (int(round(float(x))) for x in pixel.split(","))
        except (ValueError, OverflowError):
            raise FignetError(f"`prompt` {text!r}: expected VIEW:U,V (e.g. view_001.png:181,142)") from None
        if not view:
            raise FignetError(f"`prompt` {text!r}: expected VIEW:U,V (e.g. view_001.png:181,142)")
        if not (0 <= u < cameras.width and 0 <= v < cameras.height):
            raise FignetError(
                f"`prompt` {text!r}: pixel {u},{v} is outside the {cameras.width}x{cameras.height} image"
            )
        prompts.setdefault(view_index(view, cameras), []).append((u, v))
    return prompts
