"""Frames for structure from motion picked from a video with OpenCV.

The video is cut into consecutive windows of `every` frames; from each window the sharpest
frame is kept (sharpness = variance of the Laplacian of the grey image, which motion blur and
defocus lower). Frames in one window show nearly the same view, so comparing them with each
other is fair where a global threshold would not be. A window whose best frame is still
blurred — sharpness below `blur_ratio` × the median of the picks around it (the whole window
was shaken) — is dropped.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from pathlib import Path

import numpy as np

from fignetctl.errors import FignetError

log = logging.getLogger(__name__)


@dataclasses.dataclass
class PickedFrame:
    """One frame kept from the video."""

    index: int  # frame number in the video, from 0
    sharpness: float  # variance of the Laplacian
    image: np.ndarray | None  # (H, W, 3) uint8 BGR while held; None once written

    @property
    def name(self) -> str:
        return f"frame_{self.index:06d}.png"


def sharpness(image_bgr: np.ndarray, max_side: int = 640) -> float:
    """Variance of the Laplacian of the grey image, at most `max_side` pixels on a side."""
    import cv2

    grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY) if image_bgr.ndim == 3 else image_bgr
    factor = max_side / max(grey.shape)
    if factor < 1:
        grey = cv2.resize(grey, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA)
    return float(cv2.Laplacian(grey, cv2.CV_64F).var())


def _read_frames(video_path):
    """Yield (index, BGR frame) of a video; FignetError when it does not open or is empty."""
    import cv2

    video_path = Path(video_path)
    if not video_path.is_file():
        raise FignetError(f"{video_path}: no such video file")
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # our one-line error instead of ffmpeg's log
    capture = cv2.VideoCapture(str(video_path))
    try:
        if not capture.isOpened():
            raise FignetError(
                f"{video_path}: OpenCV cannot open this video (try an .mp4 or convert it with ffmpeg)"
            )
        index = 0
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            yield index, frame
            index += 1
        if index == 0:
            raise FignetError(f"{video_path}: the video has no readable frames")
    finally:
        capture.release()


def pick_frames(
    video_path, folder, every: int = 10, blur_ratio: float = 0.5, neighbours: int = 2
) -> list[PickedFrame]:
    """Write the sharpest frame of each window of `every` frames into `folder` as PNG, minus
    windows that are all blurred; return the kept frames (without their pixels).

    Only one window's best frame is held in memory at a time.
    neighbours : how many picks on each side form the median a pick is compared with
    """
    if every < 1:
        raise FignetError(f"`every` must be at least 1, not {every}")
    folder = Path(folder)
    picks: list[PickedFrame] = []
    best = None
    for index, frame in _read_frames(video_path):
        if best is not None and index // every != best.index // every:
            picks.append(_write_frame(best, folder))
            best = None
        score = sharpness(frame)
        if best is None or score > best.sharpness:
            best = PickedFrame(index, score, frame)
    picks.append(_write_frame(best, folder))
    kept = drop_blurred(picks, blur_ratio, neighbours)
    for pick in {p.name for p in picks} - {p.name for p in kept}:
        (folder / pick).unlink()
    log.info(
        "picked %d frames from %s (every %d; %d blurred windows dropped)",
        len(kept),
        video_path,
        every,
        len(picks) - len(kept),
    )
    return kept


def drop_blurred(picks: list[PickedFrame], blur_ratio: float, neighbours: int) -> list[PickedFrame]:
    """The picks whose sharpness reaches `blur_ratio` × the median of their neighbouring picks."""
    scores = np.array([p.sharpness for p in picks])
    kept = []
    for i, pick in enumerate(picks):
        around = np.concatenate([scores[max(0, i - neighbours) : i], scores[i + 1 : i + 1 + neighbours]])
        if len(around) == 0 or pick.sharpness >= blur_ratio * np.median(around):
            kept.append(pick)
    return kept


def _write_frame(frame: PickedFrame, folder: Path) -> PickedFrame:
    """Write one frame as PNG into `folder`; return it without its pixels."""
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(folder / frame.name), frame.image):
        raise FignetError(f"{folder / frame.name}: could not be written")
    return dataclasses.replace(frame, image=None)
