"""`extract-mesh` end to end: files in (nerf.pt, cameras.npz, images, prompts / masks / box),
files out (object.obj, environment.obj, volume.npz, masks/). The geometry is in
`mesh_extraction`, the masks in `segmentation`; this module reads and checks the inputs."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path

import numpy as np

from fignetctl.core.containers import read_npz_arrays, require_regular_file
from fignetctl.core.media import read_image
from fignetctl.core.mesh_extraction import (
    ExtractionSettings,
    View,
    check_mask_agreement,
    choose_threshold,
    consistent_box,
    extract_object,
    mask_agreement,
    view_masks,
    write_extraction,
)
from fignetctl.errors import FignetError, FormatError

log = logging.getLogger(__name__)


@dataclasses.dataclass
class ExtractionInputs:
    """Paths and prompts as the user gave them (exactly one of prompts, masks_dir, box)."""

    nerf: str
    cameras: str
    images: str | None = None
    prompt_texts: list = dataclasses.field(default_factory=list)  # "VIEW:U,V"
    prompts_json: str | None = None
    object_name: str | None = None
    masks_dir: str | None = None
    box: list | None = None  # x0, y0, z0, x1, y1, z1
    depth: str | None = None  # depth.npz instead of NeRF depth


def run_extraction(
    inputs: ExtractionInputs, out_dir, settings: ExtractionSettings, segmentation=None, device="cpu"
) -> dict:
    """Extract and write; returns a summary (faces, sizes, seconds, per-view mask pixels, the
    outline checks, and the provenance stamp volume.npz carries)."""
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.provenance import stamp

    started = time.perf_counter()
    cameras = read_cameras(inputs.cameras)
    model = load_nerf(inputs.nerf, device=device)
    if inputs.box is not None:
        box = np.array(inputs.box, np.float64).reshape(2, 3)
        if np.any(box[1] <= box[0]):
            raise FignetError("`box`: x1, y1, z1 must be greater than x0, y0, z0")
        views = []
    else:
        views = _masked_views(inputs, cameras, model, segmentation)
        box = consistent_box(model.density, views, settings)
    settings, threshold = _threshold(model.density, box, views, settings)
    extraction = extract_object(model.density, box, settings)
    agreement = {
        name: round(value, 3) for name, value in mask_agreement(extraction.object_mesh, views).items()
    }
    check_mask_agreement(agreement, settings)
    checks = {
        "mask_iou": agreement,
        "watertight": bool(extraction.object_mesh.is_watertight),
        "threshold": settings.threshold,
        "threshold_choice": threshold,
    }
    extra = {"inputs": {k: v for k, v in dataclasses.asdict(inputs).items() if v}, **checks}
    provenance = stamp(
        nerf=inputs.nerf,
        cameras=inputs.cameras,
        prompts=inputs.prompts_json,
        masks=inputs.masks_dir,
        depth=inputs.depth,
        images=inputs.images if views else None,
    )
    write_extraction(out_dir, extraction, settings, extra, provenance)
    _write_masks(Path(out_dir) / "masks", views)
    return {
        "object_faces": len(extraction.object_mesh.faces),
        "environment_faces": len(extraction.environment_mesh.faces),
        "object_size": np.round(extraction.object_mesh.extents, 3).tolist(),
        "lower": extraction.lower.tolist(),
        "upper": extraction.upper.tolist(),
        "origin": extraction.origin.tolist(),
        "support_z": extraction.support_z,
        "masks": {view.name: int(view.mask.sum()) for view in views},
        **checks,
        "provenance": provenance,
        "seconds": time.perf_counter() - started,
    }


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


def _masked_views(inputs, cameras, model, segmentation):
    image_dir = _image_dir(inputs, cameras)
    depth_images = _read_depth(inputs.depth, cameras) if inputs.depth else None
    if inputs.masks_dir:
        masks = read_user_masks(inputs.masks_dir, cameras)
        prompts = {index: [] for index in masks}
    else:
        prompts = (
            parse_prompts(inputs.prompt_texts, cameras)
            if inputs.prompt_texts
            else read_prompts_json(inputs.prompts_json, cameras, inputs.object_name)
        )
        masks = {}
        if len(prompts) < 2:
            raise FignetError(f"prompts are in {len(prompts)} view; give prompts in at least 2 views")
    views = []
    for index in sorted(prompts):
        view = _view(index, cameras, model, depth_images, image_dir, need_image=index not in masks)
        view.prompts, view.mask = prompts[index], masks.get(index)
        views.append(view)
    return view_masks(views, segmentation)


def _view(index, cameras, model, depth_images, image_dir, need_image):
    name = str(cameras.image_names[index])
    image = _read_image(image_dir / name, cameras) if need_image else None
    if depth_images is not None:
        return View(name, cameras.K[index], cameras.c2w[index], depth_images[index], None, image)
    rendering = model.render(cameras, index)
    depth = np.where(rendering.opacity > 0.5, rendering.depth / np.maximum(rendering.opacity, 1e-6), 0.0)
    return View(name, cameras.K[index], cameras.c2w[index], depth, rendering.opacity, image)


def _image_dir(inputs, cameras) -> Path:
    if inputs.images:
        return Path(inputs.images)
    if inputs.prompts_json and Path(inputs.prompts_json).is_file():  # never wait on a FIFO
        try:
            folder = json.loads(Path(inputs.prompts_json).read_text()).get("image_dir", "images")
            candidate = Path(inputs.prompts_json).parent / folder
            if candidate.is_dir():
                return candidate
        except (OSError, ValueError, AttributeError):
            pass
    here = Path(inputs.cameras).resolve().parent
    for candidate in (here / "images", here.parent / "images"):
        if candidate.is_dir():
            return candidate
    raise FignetError(f"no images/ folder beside or above {inputs.cameras}; give the `images`")


def _read_image(path, cameras):
    import cv2

    image = read_image(path, cv2.IMREAD_COLOR, " (are the images the right ones?)")
    if image.shape[:2] != (cameras.height, cameras.width):
        raise FormatError(
            f"{path}: is {image.shape[1]}x{image.shape[0]} but the cameras are {cameras.width}x{cameras.height}"
        )
    return np.ascontiguousarray(image[..., ::-1])


def _read_depth(path, cameras):
    arrays = read_npz_arrays(path, "depth.npz")
    if "depth" not in arrays:
        raise FormatError(f"{path}: not a depth.npz with a 'depth' array")
    depth = np.asarray(arrays["depth"], np.float64)
    if depth.shape != (len(cameras), cameras.height, cameras.width):
        raise FormatError(
            f"{path}: depth has shape {depth.shape}, expected {(len(cameras), cameras.height, cameras.width)}"
        )
    return depth


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


def read_prompts_json(path, cameras, object_name=None) -> dict:
    """prompts.json (format fignetctl.prompts v1) -> {view index: [(u, v)]} of one object."""
    path = require_regular_file(path)
    try:
        document = json.loads(path.read_text())
        if document.get("format") != "fignetctl.prompts" or document.get("format_version") != 1:
            raise ValueError("not format fignetctl.prompts version 1")
        objects = document["objects"]
        if object_name is not None:
            objects = [o for o in objects if o["name"] == object_name]
            if not objects:
                names = [o["name"] for o in document["objects"]]
                raise FignetError(f"{path}: no object {object_name!r} (it has {', '.join(names)})")
        points = objects[0]["points"]
        texts = [f"{p['image']}:{int(p['u'])},{int(p['v'])}" for p in points]
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file") from None
    except (
        OSError,
        ValueError,
        KeyError,
        TypeError,
        IndexError,
        AttributeError,
        OverflowError,
        RecursionError,
    ) as error:
        raise FormatError(f"{path}: not a usable prompts.json ({type(error).__name__}: {error})") from None
    return parse_prompts(texts, cameras)


def read_user_masks(folder, cameras) -> dict:
    """<folder>/<image stem>.png for the views that have one -> {view index: (H, W) bool}."""
    import cv2

    folder = Path(folder)
    if not folder.is_dir():
        raise FignetError(f"{folder}: no such mask folder")
    masks = {}
    for index, name in enumerate(cameras.image_names):
        path = folder / (Path(str(name)).stem + ".png")
        if not path.is_file():
            continue
        mask = read_image(path, cv2.IMREAD_GRAYSCALE)
        if mask.shape != (cameras.height, cameras.width):
            raise FormatError(f"{path}: not a {cameras.width}x{cameras.height} mask image")
        masks[index] = mask > 0
    if len(masks) < 2:
        raise FignetError(
            f"{folder}: masks for {len(masks)} of the views (named <image stem>.png); give at least 2"
        )
    return masks


def _write_masks(folder, views):
    import cv2

    from fignetctl.core.atomic import atomic_directory

    if not views:
        return
    with atomic_directory(folder, ("*.png",)) as tmp:  # one run's masks, never mixed with another's
        for view in views:
            cv2.imwrite(str(tmp / (Path(view.name).stem + ".png")), view.mask.astype(np.uint8) * 255)
