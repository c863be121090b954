"""H.264 mp4 writing (media.py), read back with PyAV and with OpenCV."""

import numpy as np
import pytest

from fignetctl.core.media import Mp4Writer, read_video_info


def gradient_frames(count, width, height):
    """Smooth frames that change over time (H.264 keeps them within a few levels)."""
    y, x = np.mgrid[0:height, 0:width]
    return [
        np.stack(
            [
                (x * 255 // max(width - 1, 1) + 7 * k) % 256,
                y * 255 // max(height - 1, 1),
                np.full_like(x, 40 * k % 256),
            ],
            axis=-1,
        ).astype(np.uint8)
        for k in range(count)
    ]


@pytest.mark.parametrize("width, height", [(64, 48), (65, 47)])
def test_frames_come_back_as_h264_of_the_same_size_count_and_colours(tmp_path, width, height):
    import av

    frames = gradient_frames(12, width, height)
    with Mp4Writer(tmp_path / "v.mp4", 15.0, width, height) as writer:
        for frame in frames:
            writer.write(frame)
    info = read_video_info(tmp_path / "v.mp4")
    assert info["codec"] == "h264" and info["frames"] == 12 and info["fps"] == pytest.approx(15.0)
    assert (info["width"], info["height"]) == (
        width + width % 2,
        height + height % 2,
    )  # odd sizes padded by one
    with av.open(str(tmp_path / "v.mp4")) as container:
        decoded = [f.to_ndarray(format="rgb24")[:height, :width] for f in container.decode(video=0)]
    errors = [np.abs(a.astype(int) - b.astype(int)).mean() for a, b in zip(decoded, frames)]
    assert len(decoded) == 12 and max(errors) < 4.0


def test_opencv_reads_the_videos_too(tmp_path):
    import cv2

    frames = gradient_frames(5, 32, 32)
    with Mp4Writer(tmp_path / "v.mp4", 30.0, 32, 32) as writer:
        for frame in frames:
            writer.write(frame)
    video = cv2.VideoCapture(str(tmp_path / "v.mp4"))
    read = []
    while True:
        ok, bgr = video.read()
        if not ok:
            break
        read.append(bgr[:, :, ::-1])
    assert len(read) == 5 and np.abs(read[2].astype(int) - frames[2].astype(int)).mean() < 4.0


def test_a_frame_of_the_wrong_size_or_type_is_refused(tmp_path):
    with Mp4Writer(tmp_path / "v.mp4", 10.0, 16, 16) as writer:
        with pytest.raises(ValueError, match=r"\(16, 16, 3\) uint8"):
            writer.write(np.zeros((16, 15, 3), np.uint8))
        with pytest.raises(ValueError):
            writer.write(np.zeros((16, 16, 3), np.float32))
        writer.write(np.zeros((16, 16, 3), np.uint8))
    assert read_video_info(tmp_path / "v.mp4")["frames"] == 1
