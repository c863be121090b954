"""extract-mesh: object and environment meshes from a NeRF and point prompts, masks or a box."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from fignetctl.errors import SettingError
from fignetctl.stages import DEVICES, check, resolve_device, setting, write_summary

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
    device: str = setting("auto", "Torch device; 'auto' uses CUDA when available.", choices=DEVICES)


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
    from fignetctl.core.object_extraction import ExtractionInputs, run_extraction
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
    summary = run_extraction(inputs, out, extraction_settings, segmentation, resolve_device(settings.device))
    provenance = summary.pop("provenance")
    summary = {"output": str(out), **summary}
    write_summary(json_path, summary, provenance)
    return {**summary, "message": _message(summary)}


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
