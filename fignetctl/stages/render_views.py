"""render-views: the bundled capture, a tabletop scene rendered with PyBullet, into a folder."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.stages import check, setting


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


def run(output, settings: Settings = Settings(), overwrite=False, progress=None) -> dict:
    """Render the capture into the folder `output` (refused if it exists, unless `overwrite`);
    returns the summary (views, objects, seconds) with a one-line `message`."""
    from fignetctl.core.synthetic_capture import render_capture

    check(settings)
    summary = render_capture(
        Path(output),
        views=settings.views,
        width=settings.width,
        height=settings.height,
        seed=settings.seed,
        video=settings.video,
        overwrite=overwrite,
        num_objects=settings.objects,
        video_step=settings.video_step,
        progress=progress,
    )
    summary["message"] = (
        f"rendered {summary['views']} views {settings.width}x{settings.height} of "
        f"{', '.join(summary['objects'])} in {summary['total_seconds']:.1f} s "
        f"({1000 * summary['seconds_per_view']:.0f} ms per view)"
    )
    return summary
