"""extract-mesh: object and environment meshes from a NeRF and point prompts, masks or a box."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

from fignetctl.errors import FignetError, FormatError, SettingError
from fignetctl.stages import check, device_setting, resolve_device, setting, write_summary

OUTPUTS = ("object.obj", "environment.obj", "volume.npz", "masks")
"""The files written into the output folder (with masks/)."""


@dataclasses.dataclass(frozen=True)
class Settings:
    prompt: tuple[str, ...] = setting(
        (),
        "A pixel on the object in a view (image name or index); repeatable, >= 2 views.",
        metavar="VIEW:U,V",
    )
    object: str | None = setting(None, "Which object of --prompts.  [default: the first]")
    box: tuple[float, ...] | None = setting(
        None, "The object's box V_o in world units, instead of masks.", metavar="X0,Y0,Z0,X1,Y1,Z1"
    )
    resolution: int = setting(96, "Grid vertices along the box's longest side.", low=8, high=512)
    threshold: str = setting(
        "auto",
        "Density threshold σ_thr (1 / world unit), or auto: the level whose mesh best matches the "
        "masks (with --box: 50).",
        metavar="auto|NUMBER",
    )
    faces: int = setting(1000, "Faces n_f after decimation (0: none).", low=0, high=10**6)
    padding: float = setting(0.1, "V_o grows by this fraction of its longest side.", low=0, high=1)
    max_size: float = setting(
        0.25, "Largest object extent (world units) for segmentation.", low=0, low_open=True
    )
    passive_margin: float = setting(0.1, "Environment box: beyond V_o horizontally (world units).", low=0)
    passive_below: float = setting(0.05, "Environment box: below the support surface.", low=0, low_open=True)
    passive_above: float | None = setting(
        None, "Environment box: above the support.  [default: V_o's height]", low=0, low_open=True
    )
    carve: bool = setting(
        True,
        "Cut the object's density to the masks' visual hull and to what the views see through, and fill "
        "what no view saw inside it.",
    )
    outline_votes: int = setting(
        3,
        "With --carve: the views nobody prompted carve the object too where this many of them agree "
        "(masks drawn around the first mesh's outline); 0: only the prompted views carve.",
        low=0,
        high=100,
    )
    max_voxel: float = setting(
        0.1,
        "Refuse the mesh when the NeRF's voxel is over this fraction of its smallest side (too coarse "
        "to measure: a side can be off by a voxel).",
        low=0,
        low_open=True,
    )
    device: str = device_setting()


def run(
    nerf,
    output,
    settings: Settings = Settings(),
    *,
    cameras,
    images=None,
    prompts=None,
    masks=None,
    depth=None,
    json_path=None,
) -> dict:
    """Extract the object's mesh and its environment's from the field `nerf` (nerf.pt) seen by
    `cameras` (cameras.npz; images from `images`, by default images/ beside or above it). The
    object is given by exactly one of: `settings.prompt` or a prompts.json (`prompts`, with
    `settings.object`), a folder of user `masks`, or `settings.box`; `depth` (depth.npz) can
    replace NeRF depth. `settings.threshold` "auto" chooses σ_thr from the masks
    (`mesh_extraction.choose_threshold`; with a box: THRESHOLD), a number sets it. Writes
    object.obj, environment.obj, volume.npz and masks/ into the folder `output`, and the --json
    summary (with `threshold` and `threshold_choice`). Returns the summary with a one-line `message`."""
    from fignetctl.core.mesh_extraction import THRESHOLD, ExtractionSettings
    from fignetctl.core.segmentation import SegmentationSettings

    check(settings)
    given = [bool(settings.prompt or prompts), bool(masks), settings.box is not None]
    if sum(given) != 1:
        raise SettingError("give exactly one of --prompt/--prompts, --masks or --box")
    _check_box(settings.box)
    threshold = parse_threshold(settings.threshold)
    out = Path(output)
    extraction_settings = ExtractionSettings(
        resolution=settings.resolution,
        threshold=THRESHOLD if threshold == "auto" else threshold,
        auto_threshold=threshold == "auto",
        faces=settings.faces,
        padding=settings.padding,
        passive_margin=settings.passive_margin,
        passive_below=settings.passive_below,
        passive_above=settings.passive_above,
        carve_margin=ExtractionSettings.carve_margin if settings.carve else None,
        max_voxel=settings.max_voxel,
        outline_votes=settings.outline_votes,
    )
    inputs = ExtractionInputs(
        nerf=nerf,
        cameras=cameras,
        images=images,
        prompt_texts=list(settings.prompt),
        prompts_json=prompts,
        object_name=settings.object,
        masks_dir=masks,
        box=None if settings.box is None else list(settings.box),
        depth=depth,
    )
    segmentation = SegmentationSettings(max_size=settings.max_size)
    summary = _extract(inputs, out, extraction_settings, segmentation, resolve_device(settings.device))
    provenance = summary.pop("provenance")
    summary = {"output": str(out), **summary}
    write_summary(json_path, summary, provenance)
    return {**summary, "message": _message(summary)}


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


def _extract(inputs: ExtractionInputs, out_dir, settings, segmentation=None, device="cpu") -> dict:
    """Read the inputs, extract (`object_extraction.extract`) and write; returns a summary
    (faces, sizes, seconds, per-view mask pixels, the outline checks, and the provenance stamp
    volume.npz carries)."""
    import numpy as np

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.object_extraction import extract, unprompted_views
    from fignetctl.core.provenance import stamp
    from fignetctl.core.segmentation import SegmentationSettings

    started = time.perf_counter()
    cameras = read_cameras(inputs.cameras)
    model = load_nerf(inputs.nerf, device=device)
    voxel = model.voxel_size
    # a coarse field's depth scatters by about a voxel: the masks' plane fits allow for it
    segmentation = dataclasses.replace(segmentation or SegmentationSettings(), depth_noise=voxel)
    views = [] if inputs.box is not None else _views(inputs, cameras, model)
    more_views = None
    if views and not inputs.masks_dir:
        image_dir = _image_dir(inputs, cameras)
        prompted = {cameras.index_of(view.name) for view in views}
        read = lambda index: _read_image(image_dir / str(cameras.image_names[index]), cameras)
        more_views = unprompted_views(cameras, model, read, prompted)
    result = extract(
        model.density, settings, views, inputs.box, segmentation, voxel, more_views, model.region
    )
    extraction, views, checks = result.extraction, result.views, result.checks
    extra = {"inputs": {k: v for k, v in dataclasses.asdict(inputs).items() if v}, **checks}
    provenance = stamp(
        nerf=inputs.nerf,
        cameras=inputs.cameras,
        prompts=inputs.prompts_json,
        masks=inputs.masks_dir,
        depth=inputs.depth,
        images=inputs.images if views else None,
    )
    write_extraction(out_dir, extraction, result.settings, extra, provenance)
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


def _views(inputs: ExtractionInputs, cameras, model) -> list:
    """The prompted or masked views (`mesh_extraction.View`), their images, depth, prompts
    and user masks read from the files given."""
    from fignetctl.core.object_extraction import parse_prompts, prompted_view

    image_dir = _image_dir(inputs, cameras)
    depth_images = read_depth(inputs.depth, cameras) if inputs.depth else None
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
        name = str(cameras.image_names[index])
        image = _read_image(image_dir / name, cameras) if index not in masks else None
        view = prompted_view(index, cameras, model, depth_images, image)
        view.prompts, view.mask = prompts[index], masks.get(index)
        views.append(view)
    return views


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
    import numpy as np

    from fignetctl.core.media import read_image

    image = read_image(path, cv2.IMREAD_COLOR, " (are the images the right ones?)")
    if image.shape[:2] != (cameras.height, cameras.width):
        raise FormatError(
            f"{path}: is {image.shape[1]}x{image.shape[0]} but the cameras are {cameras.width}x{cameras.height}"
        )
    return np.ascontiguousarray(image[..., ::-1])


def read_depth(path, cameras):
    """depth.npz (depth (N, H, W) of the views of `cameras`) -> (N, H, W) float64."""
    import numpy as np

    from fignetctl.core.containers import read_npz_arrays

    arrays = read_npz_arrays(path, "depth.npz")
    if "depth" not in arrays:
        raise FormatError(f"{path}: not a depth.npz with a 'depth' array")
    depth = np.asarray(arrays["depth"], np.float64)
    if depth.shape != (len(cameras), cameras.height, cameras.width):
        raise FormatError(
            f"{path}: depth has shape {depth.shape}, expected {(len(cameras), cameras.height, cameras.width)}"
        )
    return depth


def read_prompts_json(path, cameras, object_name=None) -> dict:
    """prompts.json (format fignetctl.prompts v1) -> {view index: [(u, v)]} of one object."""
    from fignetctl.core.containers import require_regular_file
    from fignetctl.core.object_extraction import parse_prompts

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

    from fignetctl.core.media import read_image

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


def write_extraction(out_dir, extraction, settings, extra_settings=None, provenance=None):
    """object.obj (vertices relative to the origin), environment.obj (world), volume.npz (stamped
    with `provenance`) of a `mesh_extraction.Extraction` made with `settings`."""
    from fignetctl.core.obj import write_obj
    from fignetctl.core.volume import Volume, write_volume

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    object_mesh = extraction.object_mesh.copy()
    object_mesh.apply_translation(-extraction.origin)
    for name, mesh in (("object.obj", object_mesh), ("environment.obj", extraction.environment_mesh)):
        write_obj(out_dir / name, mesh.vertices, mesh.faces)
    volume = Volume(
        lower=extraction.lower,
        upper=extraction.upper,
        origin=extraction.origin,
        passive_lower=extraction.passive_lower,
        passive_upper=extraction.passive_upper,
        settings={**settings.to_dict(), **(extra_settings or {}), "support_z": extraction.support_z},
    )
    write_volume(out_dir / "volume.npz", volume, provenance)
    return volume


def _write_masks(folder, views):
    import cv2
    import numpy as np

    from fignetctl.core.atomic import atomic_directory

    if not views:
        return
    with atomic_directory(folder, ("*.png",)) as tmp:  # one run's masks, never mixed with another's
        for view in views:
            cv2.imwrite(str(tmp / (Path(view.name).stem + ".png")), view.mask.astype(np.uint8) * 255)


def parse_threshold(value):
    """`threshold` as "auto" or a positive finite float (a number or its text); else SettingError."""
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    try:
        number = math.nan if isinstance(value, bool) else float(value)
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise SettingError(f"`threshold` {value!r}: give auto or a positive finite number (1 / world unit)")
    return number


def _check_box(box) -> None:
    """A box is 6 finite numbers within ±1e6 (as --box parses them)."""
    if box is None:
        return
    try:
        numbers = [float(x) for x in box]
    except (TypeError, ValueError):
        numbers = []
    if len(numbers) != 6 or not all(math.isfinite(x) and abs(x) <= 1e6 for x in numbers):
        raise SettingError(f"box = {box!r}: give 6 finite numbers within ±1e6 (x0, y0, z0, x1, y1, z1)")


def _message(summary) -> str:
    """The success line: faces and size of the object, outline agreement, environment faces, time."""
    agreement = summary["mask_iou"]
    outline = (
        f"; outline vs masks IoU {min(agreement.values()):.2f}-{max(agreement.values()):.2f}"
        if agreement
        else ""
    )
    return (
        f"object: {summary['object_faces']} faces, {summary['object_size']} world units"
        f"{'' if summary['watertight'] else ' (not watertight)'}; {_threshold_note(summary)}{outline}; "
        f"environment: {summary['environment_faces']} faces; {summary['seconds']:.1f} s"
        + (
            f"; {len(warned)} warning{'s' * (len(warned) > 1)} above"
            if (warned := summary.get("warnings"))
            else ""
        )
    )


def _threshold_note(summary) -> str:
    """How σ_thr was set: "threshold 35.4 (auto: ...)"."""
    choice, threshold = summary["threshold_choice"], f"threshold {summary['threshold']:g}"
    if choice["source"] == "given":
        return threshold
    if choice["source"] != "masks":
        return f"{threshold} (auto: no masks to choose it from, so the default)"
    best = choice["scores"][f"{summary['threshold']:g}"]
    return (
        f"{threshold} (auto: best median outline IoU {best:.2f} of {len(choice['scores'])} levels "
        f"{min(map(float, choice['scores'])):g}-{max(map(float, choice['scores'])):g}, {choice['seconds']:.1f} s)"
    )
