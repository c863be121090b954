"""What mesh accuracy costs in time: extract-mesh on the bundled capture for several --faces.

For each object of the capture's prompts.json: mask IoU of the prompted views against the
ground-truth masks (single-view GrabCut masks, and the final masks redrawn from the visual hull), then for each n_f the extraction time and the mesh against the GT mesh
(symmetric Chamfer distance and volume IoU, as fractions of the object's largest side).

    python benchmarks/bench_extract_mesh.py --capture capture --nerf nerf.pt
    python benchmarks/bench_extract_mesh.py --capture capture --nerf nerf.pt --cameras cameras.npz   # fitted on capture-poses' cameras
    python benchmarks/bench_extract_mesh.py --capture capture --carve     # GT depth instead of a NeRF

--cameras: the cameras the NeRF was fitted with, when they are not the ground truth's (the
capture-poses frame); the GT meshes are then moved into that frame by the similarity that best
maps the GT camera centres onto those cameras' centres (Umeyama).

--carve builds a stand-in NeRF by space carving the capture's GT depth (every view's depth
bounds the solid), so the geometry stages can be measured without NeRF error. Writes
benchmarks/results/extract_mesh.json and docs/images/extract-mesh-faces.png.
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from mesh_vs_truth import chamfer, truth_to

from fignetctl.core.atomic import write_json

FACES = (100, 300, 1000, 3000, 0)


def mesh_errors(mesh, truth, samples=20000, seed=0):
    """(chamfer, volume IoU) as fractions: the symmetric mean closest-point distance over the
    truth's largest side, and the IoU of both meshes voxelised (pitch 1/64 of that side) and
    filled. The IoU is None when the truth is not watertight (the lego brick is open
    underneath, the mug has a cavity): its inside is then not defined."""
    distance = chamfer(mesh, truth, samples, seed)
    if not truth.is_watertight:
        return distance / float(truth.extents.max()), None
    pitch = truth.extents.max() / 64
    solid_a, solid_b = mesh.voxelized(pitch).fill(), truth.voxelized(pitch).fill()
    low = np.minimum(mesh.bounds[0], truth.bounds[0])
    high = np.maximum(mesh.bounds[1], truth.bounds[1])
    points = np.random.default_rng(seed).uniform(low, high, size=(40000, 3))
    inside_a, inside_b = solid_a.is_filled(points), solid_b.is_filled(points)
    iou = (inside_a & inside_b).sum() / max((inside_a | inside_b).sum(), 1)
    return distance / float(truth.extents.max()), float(iou)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", type=Path, required=True)
    parser.add_argument("--nerf", type=Path)
    parser.add_argument(
        "--cameras", type=Path, help="cameras the NeRF was fitted with (default: the GT cameras)"
    )
    parser.add_argument("--carve", action="store_true", help="GT-depth carving instead of a trained NeRF")
    parser.add_argument("--threshold", type=float, default=50.0)
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--output", type=Path, default=ROOT / "benchmarks" / "results" / "extract_mesh.json")
    parser.add_argument("--plot", type=Path, default=ROOT / "docs" / "images" / "extract-mesh-faces.png")
    args = parser.parse_args()
    import cv2
    import trimesh

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.mesh_extraction import (
        ExtractionSettings,
        View,
        consistent_box,
        extract_object,
        view_masks,
    )
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.segmentation import iou

    capture = args.capture
    truth_cameras = read_cameras(capture / "ground_truth" / "cameras.npz")
    cameras = read_cameras(args.cameras) if args.cameras else truth_cameras
    to_nerf_frame = truth_to(cameras, truth_cameras)
    truth_masks = np.load(capture / "ground_truth" / "masks.npz")["masks"]
    nerf_path = args.nerf
    if args.carve:
        from tests.core.carved_scene import carved_nerf

        depth = np.load(capture / "ground_truth" / "depth.npz")["depth"]
        nerf_path = capture / "carved_nerf.pt"
        carved_nerf(
            nerf_path, depth, cameras, np.array([[-0.35, -0.35, -0.04], [0.35, 0.35, 0.25]]), resolution=192
        )
    model = load_nerf(nerf_path)
    results = {
        "capture": str(capture),
        "cameras": str(args.cameras or "ground truth"),
        "density": "GT-depth carving (192^3 grid)" if args.carve else f"NeRF {nerf_path}",
        "nerf_metrics": {k: v for k, v in model.metrics.items() if k != "held_out"},
        "threshold": args.threshold,
        "resolution": args.resolution,
        "objects": [],
    }
    for obj in json.loads((capture / "prompts.json").read_text())["objects"]:
        views = []
        started = time.perf_counter()
        for point in obj["points"]:
            index = cameras.index_of(point["image"])
            image = cv2.imread(str(capture / "images" / point["image"]))[..., ::-1].copy()
            rendering = model.render(cameras, index)
            depth_image = np.where(
                rendering.opacity > 0.5, rendering.depth / np.maximum(rendering.opacity, 1e-6), 0.0
            )
            views.append(
                View(
                    point["image"],
                    cameras.K[index],
                    cameras.c2w[index],
                    depth_image,
                    rendering.opacity,
                    image,
                    [(point["u"], point["v"])],
                )
            )
        view_masks(views)
        first_ious = {v.name: iou(v.mask, truth_masks[cameras.index_of(v.name)] == obj["id"]) for v in views}
        settings = ExtractionSettings(threshold=args.threshold)
        box = consistent_box(model.density, views, settings)
        mask_seconds = time.perf_counter() - started
        ious = {v.name: iou(v.mask, truth_masks[cameras.index_of(v.name)] == obj["id"]) for v in views}
        truth = trimesh.load(capture / "ground_truth" / "objects" / f"{obj['name']}.obj", force="mesh")
        truth.apply_transform(to_nerf_frame)
        rows = []
        for faces in FACES:
            settings = ExtractionSettings(resolution=args.resolution, threshold=args.threshold, faces=faces)
            started = time.perf_counter()
            extraction = extract_object(model.density, box, settings)
            seconds = time.perf_counter() - started
            chamfer_fraction, volume_iou = mesh_errors(extraction.object_mesh, truth)
            rows.append(
                {
                    "faces": faces,
                    "faces_made": len(extraction.object_mesh.faces),
                    "seconds": round(seconds, 3),
                    "chamfer_fraction": round(chamfer_fraction, 4),
                    "volume_iou": None if volume_iou is None else round(volume_iou, 3),
                    "watertight": bool(extraction.object_mesh.is_watertight),
                }
            )
            print(obj["name"], rows[-1], flush=True)
        results["objects"].append(
            {
                "name": obj["name"],
                "mask_iou": {k: round(v, 3) for k, v in ious.items()},
                "mask_iou_single_view": {k: round(v, 3) for k, v in first_ious.items()},
                "mask_seconds": round(mask_seconds, 2),
                "size": truth.extents.round(3).tolist(),
                "box": np.asarray(box).round(3).tolist(),
                "faces": rows,
            }
        )
        print(obj["name"], "mask IoU", results["objects"][-1]["mask_iou"], flush=True)
    write_json(args.output, results)
    plot(results, args.plot)


def plot(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    for obj in results["objects"]:
        rows = obj["faces"]
        x = [r["faces_made"] for r in rows]
        axes[0].plot(x, [100 * r["chamfer_fraction"] for r in rows], "o-", label=obj["name"])
        axes[1].plot(
            [r["seconds"] for r in rows], [100 * r["chamfer_fraction"] for r in rows], "o", label=obj["name"]
        )
    axes[0].set(xscale="log", xlabel="faces of the object mesh", ylabel="Chamfer, % of object size")
    axes[1].set(xlabel="extraction seconds (object + environment)", ylabel="Chamfer, % of object size")
    axes[0].legend()
    density = results["density"] if results["density"].startswith("GT") else "fitted NeRF, fast preset"
    figure.suptitle(f"extract-mesh on the bundled capture ({density})", fontsize=9)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
