"""The README's picture of the main job: the capture's view, then frames of the re-rendered video.

    python benchmarks/pipeline_strip.py out/scene --view 5 --frames 0 10 20 45 \
        -o docs/images/pipeline-strip.png
"""

import argparse
from pathlib import Path

import numpy as np
from PIL import Image


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="the main job's output folder (out/scene)")
    parser.add_argument(
        "--view", type=int, default=5, help="the capture view rerender used (pipeline.mk's VIEW)"
    )
    parser.add_argument("--frames", type=int, nargs="+", default=[0, 10, 20, 45])
    parser.add_argument("-o", "--output", type=Path, required=True)
    args = parser.parse_args()
    paths = [args.scene / "capture" / "images" / f"view_{args.view:03d}.png"]
    paths += [args.scene / "video_frames" / f"frame_{frame:05d}.png" for frame in args.frames]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise SystemExit(f"error: missing {', '.join(missing)}; run `make demo` first")
    images = [np.asarray(Image.open(p).convert("RGB")) for p in paths]
    height = min(image.shape[0] for image in images)
    strip = np.concatenate([image[:height] for image in images], axis=1)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(strip).save(args.output)
    print(args.output)


if __name__ == "__main__":
    main()
