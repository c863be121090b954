"""Images read through OpenCV with one-line errors, and videos: H.264 mp4 files (what
browsers, players and rerun open), written through PyAV.

Frames are (H, W, 3) uint8 RGB. H.264 in yuv420p needs an even width and height: a frame of
odd size is padded by repeating its last row or column, so the video is at most one pixel
wider and taller than the frames.
"""

from __future__ import annotations

import fractions

import numpy as np

from fignetctl.errors import FignetError, FormatError


def read_image(path, flags=None, hint: str = "") -> np.ndarray:
    """An image as OpenCV reads it (`flags`: cv2.IMREAD_*, default IMREAD_UNCHANGED), or a
    one-line FormatError naming `path` (`hint`: what to check, appended to it) when it is not a
    regular file, cannot be decoded, or declares more pixels than OpenCV's limit (a
    'decompression bomb': a small file whose header claims a huge image)."""
    import cv2

    from fignetctl.core.containers import require_regular_file

    path = require_regular_file(path, "image")
    try:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED if flags is None else flags)
    except cv2.error as error:
        too_large = "MAX_IMAGE_PIXELS" in str(error)
        raise FormatError(
            f"{path}: "
            + ("declares more pixels than OpenCV reads; resize it" if too_large else "not a readable image")
            + hint
        ) from None
    if image is None or image.size == 0:
        raise FormatError(f"{path}: not a readable image{hint}")
    return image


CODEC = "libx264"
QUALITY_CRF = 18  # x264's constant rate factor: 18 is visually lossless for most content


class Mp4Writer:
    """Write frames to an H.264 mp4 at `fps` frames per second; use as a context manager (the
    file is complete once it is closed) or call close()."""

    def __init__(self, path, fps: float, width: int, height: int):
        try:
            import av
        except ImportError:
            raise FignetError("writing videos needs PyAV: pip install av") from None
        if not (np.isfinite(fps) and fps > 0) or width < 1 or height < 1:
            raise FignetError(
                f"{path}: cannot write a video of {width}x{height} pixels at {fps} frames per second"
            )
        self.path, self.size = path, (int(width), int(height))
        self._container = av.open(str(path), "w", format="mp4")
        self._stream = self._container.add_stream(
            CODEC, rate=fractions.Fraction(float(fps)).limit_denominator(1001)
        )
        self._stream.width, self._stream.height = (int(width) + 1) // 2 * 2, (int(height) + 1) // 2 * 2
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = {"crf": str(QUALITY_CRF)}
        self._av = av
        self.frames = 0

    def write(self, rgb) -> None:
        """Append one (H, W, 3) uint8 RGB frame of the writer's size."""
        rgb = np.asarray(rgb)
        if rgb.shape != (self.size[1], self.size[0], 3) or rgb.dtype != np.uint8:
            raise ValueError(
                f"a frame must be ({self.size[1]}, {self.size[0]}, 3) uint8, not {rgb.shape} {rgb.dtype}"
            )
        padding = ((0, self._stream.height - rgb.shape[0]), (0, self._stream.width - rgb.shape[1]), (0, 0))
        frame = self._av.VideoFrame.from_ndarray(
            np.ascontiguousarray(np.pad(rgb, padding, mode="edge")), format="rgb24"
        )
        self._mux(self._stream.encode(frame))
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file (once)."""
        if self._container is None:
            return
        try:
            self._mux(self._stream.encode(None))
        finally:
            self._container.close()
            self._container = None

    def _mux(self, packets) -> None:
        for packet in packets:
            self._container.mux(packet)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_video_info(path) -> dict:
    """{"codec", "width", "height", "frames", "fps"} of a video file's first video stream."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = stream.frames or sum(1 for _ in container.decode(stream))
        return {
            "codec": stream.codec_context.name,
            "width": stream.codec_context.width,
            "height": stream.codec_context.height,
            "frames": int(frames),
            "fps": float(stream.average_rate or 0),
        }
