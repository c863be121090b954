"""A capture recorded through a distorting lens, against the same capture through a pinhole.

The bundled capture (render-views, 40 views 320×240) is seen through radial distortion k1
(OpenCV's model, default 0.15, pincushion) and taken through the main job's first two stages
as a user would: capture-poses with --camera-model SIMPLE_RADIAL (the images undistorted), then
fit-nerf --preset fast. Beside it, the pinhole images through the same two stages, and the
distorted images posed as if they were pinhole (the lens ignored, what a pinhole-only tool
does). Reported: registered views, the estimated lens, and held-out PSNR of each fit. The
issue's bar: within 0.5 dB of the pinhole capture.

    .venv/bin/python benchmarks/bench_distortion.py -o benchmarks/results/distortion.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

from fignetctl.core.atomic import atomic_path
from fignetctl.core.cameras import read_cameras

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.core.synthetic_views import distort_image

FIGNETCTL = [str(Path(sys.executable).parent / "fignetctl")]


def fignetctl(*args) -> float:
    """Run one command as a user would; its wall time in seconds."""
    started = time.perf_counter()
    subprocess.run([*FIGNETCTL, *map(str, args)], check=True)
    return time.perf_counter() - started


def case(name, images, work, camera_model, height, steps) -> dict:
    out = work / name
    poses = ["--images", images, "--camera-model", camera_model, "--camera-height", height]
    pose_seconds = fignetctl("capture-poses", *poses, "-o", out / "cameras.npz", "--json", out / "poses.json")
    summary = json.loads((out / "poses.json").read_text())
    fit = ["--preset", "fast", "--device", "cpu", "--json", out / "nerf.json"]
    if steps:
        fit += ["--steps", steps]
    fit_seconds = fignetctl("fit-nerf", summary["images"], out / "cameras.npz", "-o", out / "nerf.pt", *fit)
    nerf = json.loads((out / "nerf.json").read_text())
    cameras = read_cameras(out / "cameras.npz")
    return {
        "camera_model": camera_model,
        "registered": len(cameras),
        "image_size": [cameras.width, cameras.height],
        "focal_px": float(cameras.K[0, 0, 0]),
        "held_out_psnr_db": nerf["held_out_psnr"],
        "capture_poses_seconds": pose_seconds,
        "fit_nerf_seconds": fit_seconds,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--k1", type=float, default=0.15)
    parser.add_argument("--steps", type=int, default=None, help="fit-nerf steps (default: the fast preset's)")
    parser.add_argument("-o", "--output", default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="fignetctl-distortion-") as work:
        work = Path(work)
        fignetctl("render-views", "-o", work / "capture", "--no-video")
        truth = read_cameras(work / "capture" / "ground_truth" / "cameras.npz")
        height = float(truth.centres[:, 2].mean())  # above the table top, z = 0: what a user measures
        distorted = work / "distorted"
        distorted.mkdir()
        for name, K in zip(truth.image_names, truth.K):
            image = cv2.imread(str(work / "capture" / "images" / name))
            cv2.imwrite(str(distorted / name), distort_image(image, K, args.k1))
        results = {
            "pinhole images, SIMPLE_PINHOLE": case(
                "pinhole", work / "capture" / "images", work, "SIMPLE_PINHOLE", height, args.steps
            ),
            f"k1 = {args.k1} images, SIMPLE_RADIAL (undistorted)": case(
                "radial", distorted, work, "SIMPLE_RADIAL", height, args.steps
            ),
            f"k1 = {args.k1} images, SIMPLE_PINHOLE (lens ignored)": case(
                "ignored", distorted, work, "SIMPLE_PINHOLE", height, args.steps
            ),
        }
    pinhole = results["pinhole images, SIMPLE_PINHOLE"]["held_out_psnr_db"]
    for result in results.values():
        result["psnr_minus_pinhole_db"] = result["held_out_psnr_db"] - pinhole
    report = {"k1": args.k1, "true_focal_px": float(truth.K[0, 0, 0]), "results": results}
    print(json.dumps(report, indent=1))
    if args.output:
        with atomic_path(args.output) as tmp:
            tmp.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
