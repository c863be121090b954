"""render-views: the bundled capture, a tabletop scene rendered with PyBullet, into a folder."""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

from fignetctl.errors import FignetError
from fignetctl.stages import check, setting

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Settings:
    views: int = setting(40, "Still views on the orbit.", low=2, high=10**4)
    width: int = setting(320, "Image width, pixels.", low=16, high=4096)
    height: int = setting(240, "Image height, pixels.", low=16, high=4096)
    objects: int = setting(3, "Everyday objects in the tray.", low=2, high=4)
    video_step: int = setting(
        3, "Video frames per view interval (video frame k*step is view k).", low=1, high=10**4
    )
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    video: bool = setting(True, "Write video.mp4 (a slow orbit through the views).")


CAPTURE_ENTRIES = ("images", "ground_truth", "video.mp4", "prompts.json", "measurements.json")
"""What a capture folder holds: replacing one that holds anything else is refused."""


def run(output, settings: Settings = Settings(), overwrite=False, progress=None) -> dict:
    """Render the capture into the folder `output` (refused if it exists, unless `overwrite`);
    returns the summary (views, objects, seconds) with a one-line `message`."""
    from fignetctl.core.synthetic_capture import capture_settings

    check(settings)
    values = dataclasses.asdict(settings)  # CaptureSettings fields, but for `objects`
    config = capture_settings(num_objects=values.pop("objects"), **values)
    summary = write_capture(Path(output), config, overwrite, progress)
    summary["message"] = (
        f"rendered {summary['views']} views {settings.width}x{settings.height} of "
        f"{', '.join(summary['objects'])} in {summary['total_seconds']:.1f} s "
        f"({1000 * summary['seconds_per_view']:.0f} ms per view)"
    )
    return summary


def write_capture(output, config=None, overwrite=False, progress=None) -> dict:
    """Render the bundled capture with `config` (a `synthetic_capture.CaptureSettings`; default:
    its defaults) and write it into the folder `output`, atomically (see
    `fignetctl.core.synthetic_capture`). Refuses an existing `output` unless `overwrite`.
    `progress`, if given, wraps an iterable (e.g. a tqdm bar). Returns a summary dict (views,
    objects, seconds, output)."""
    import contextlib

    from fignetctl.core.atomic import atomic_directory
    from fignetctl.core.media import Mp4Writer
    from fignetctl.core.synthetic_capture import CaptureSettings, render_capture

    config = config or CaptureSettings()
    output = Path(output)
    if output.exists() and not overwrite:
        raise FignetError(f"{output} exists; pass `overwrite` to replace it")
    start = time.perf_counter()
    with atomic_directory(output, CAPTURE_ENTRIES) as tmp:
        with contextlib.ExitStack() as stack:
            video = None
            if config.video:
                size = (config.video_fps, config.width, config.height)
                video = stack.enter_context(Mp4Writer(tmp / "video.mp4", *size))
            capture = render_capture(config, progress, video and video.write)
        _write_views(tmp, capture)
        total = time.perf_counter() - start
        summary = {**capture.summary, "total_seconds": round(total, 3)}
        log.info(
            "rendered %d views %dx%d in %.2f s (%.1f ms per view)",
            config.views,
            config.width,
            config.height,
            total,
            1000 * capture.render_seconds / config.views,
        )
        _write_json(tmp / "ground_truth" / "scene.json", capture.scene | {"summary": summary})
    return summary | {"output": str(output)}


def _write_views(folder: Path, capture) -> None:
    """images/, ground_truth/ (cameras.npz, depth.npz, masks.npz, objects/), prompts.json and
    measurements.json of `capture` into `folder`."""
    import cv2
    import numpy as np

    from fignetctl.core.cameras import write_cameras
    from fignetctl.core.obj import write_obj

    images, ground_truth = folder / "images", folder / "ground_truth"
    (ground_truth / "objects").mkdir(parents=True)
    images.mkdir()
    names = capture.cameras.image_names
    for name, image in zip(names, capture.rgb):
        if not cv2.imwrite(str(images / name), np.ascontiguousarray(image[:, :, ::-1])):
            raise FignetError(f"cannot write {images / name}")
    write_cameras(ground_truth / "cameras.npz", capture.cameras)
    np.savez_compressed(ground_truth / "depth.npz", depth=capture.depth, image_names=names)
    np.savez_compressed(
        ground_truth / "masks.npz",
        masks=capture.masks,
        ids=np.array([o.id for o in capture.objects], np.int16),
        names=np.array([o.name for o in capture.objects]),
        image_names=names,
    )
    for item in capture.objects:
        write_obj(ground_truth / "objects" / f"{item.name}.obj", item.vertices, item.faces)
    _write_json(folder / "prompts.json", capture.prompts)
    _write_json(folder / "measurements.json", capture.measurements)


def _write_json(path: Path, document: dict) -> None:
    import json

    path.write_text(json.dumps(document, indent=1))
