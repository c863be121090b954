"""Rendered depth of NeRFs against the true depth of a capture with ground truth (render-views'
or benchmarks/foreign_capture.py's layout), over the held-out views' pixels whose true surface
lies in a box (by default the objects' box of `fit-nerf --region prompts`).

The NeRF lives in capture-poses' frame; the true cameras in the capture's. A similarity
(Umeyama, camera centres) maps the true surface points into the NeRF's frame and its scale
turns the rendered z-depth back into the capture's metres. Reports the median absolute depth
error and the share of pixels off by more than 2 and 5 cm.

    python benchmarks/nerf_depth_vs_truth.py --capture /tmp/fc/capture \\
        --box-from /tmp/fc/fit-nerf-prompts.json NERF.pt CAMERAS.npz [NERF.pt CAMERAS.npz ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_foreign_capture import umeyama

from fignetctl.core.atomic import write_json
from fignetctl.core.nerf.io import load_nerf
from fignetctl.core.pinhole import camera_frame_points


def depth_errors(nerf_path, cameras_path, truth_cameras, truth_depth, box):
    estimated = np.load(cameras_path)
    scale, rotation, shift = umeyama(truth_cameras["c2w"][:, :3, 3], estimated["c2w"][:, :3, 3])
    model = load_nerf(nerf_path)
    width, height = int(truth_cameras["width"]), int(truth_cameras["height"])
    errors, per_view = [], {}
    for view in model.inputs["held_out_views"]:
        depth = truth_depth[view]
        c2w = truth_cameras["c2w"][view]
        world = camera_frame_points(depth, truth_cameras["K"][view]) @ c2w[:3, :3].T + c2w[:3, 3]
        points = scale * world @ rotation.T + shift
        inside = np.isfinite(depth) & (depth > 0) & np.all((points >= box[0]) & (points <= box[1]), -1)
        rendering = model.render((estimated["K"][view], estimated["c2w"][view], width, height))
        error = np.abs(rendering.depth / scale - depth)[inside]
        errors.append(error)
        per_view[int(view)] = {"pixels": int(inside.sum()), "median_m": float(np.median(error))}
    error = np.concatenate(errors)
    return {
        "nerf": str(nerf_path),
        "near": model.config.near,
        "background": model.config.background,
        "held_out_psnr": model.metrics.get("held_out_psnr"),
        "pixels": int(error.size),
        "median_abs_error_m": float(np.median(error)),
        "share_over_2cm": float((error > 0.02).mean()),
        "share_over_5cm": float((error > 0.05).mean()),
        "per_view": per_view,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capture", type=Path, required=True, help="holds ground_truth/{cameras,depth}.npz")
    parser.add_argument(
        "--box-from", type=Path, required=True, help="a fit-nerf --json summary with a region"
    )
    parser.add_argument("pairs", nargs="+", help="NERF.pt CAMERAS.npz, repeated")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/nerf-depth-vs-truth.json"))
    args = parser.parse_args()
    if len(args.pairs) % 2:
        parser.error("give NERF.pt CAMERAS.npz pairs")
    torch.set_num_threads(1)
    truth_cameras = np.load(args.capture / "ground_truth" / "cameras.npz")
    truth_depth = np.load(args.capture / "ground_truth" / "depth.npz")["depth"]
    box = np.asarray(json.loads(args.box_from.read_text())["region"])
    results = []
    for nerf, cameras in zip(args.pairs[::2], args.pairs[1::2]):
        result = depth_errors(nerf, cameras, truth_cameras, truth_depth, box)
        results.append(result)
        print(
            f"{nerf}: background {result['background']}, near {result['near']:.3f}: depth error median "
            f"{100 * result['median_abs_error_m']:.1f} cm, > 2 cm {100 * result['share_over_2cm']:.0f} %, "
            f"> 5 cm {100 * result['share_over_5cm']:.0f} % of {result['pixels']} pixels",
            flush=True,
        )
    write_json(args.out, {"box": box.tolist(), "results": results})


if __name__ == "__main__":
    main()
