"""A NeRF box around what matters: fit-nerf over the whole scene box (--region scene) against
fine grids in a region (--region prompts, support:H or a box) with a coarse grid elsewhere.

For each region, one fit through the fit-nerf stage (the fast preset by default) on a capture
with ground-truth cameras; records training seconds, held-out PSNR, region PSNR (on the
held-out pixels whose rays pass through the prompts region, the same pixels for every run),
training and CPU seconds (CPU: all threads, evaluation included; fairer than wall time on a
shared machine, as is --parallel, which runs the fits side by side),
the density-grid voxel size in the region and outside, and the smallest prompted object's size
(largest extent of its ground-truth mesh) over that voxel size (the issue asks for >= 20).

    python benchmarks/bench_nerf_region.py                          # the bundled capture (seed 0)
    python benchmarks/bench_nerf_region.py --capture DIR --regions scene prompts support:0.3
    python benchmarks/bench_nerf_region.py --steps 300 --parallel --threads 1   # side by side

Writes benchmarks/results/nerf_region.json (or --out).
"""

import argparse
import dataclasses
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from fignetctl.core.atomic import write_json

ROOT = Path(__file__).resolve().parents[1]


def capture_folder(path, seed):
    if path is not None:
        return Path(path)
    from fignetctl.core.synthetic_capture import capture_settings
    from fignetctl.stages.render_views import write_capture

    folder = Path(tempfile.mkdtemp(prefix="bench-nerf-region-")) / "capture"
    write_capture(folder, capture_settings(video=False, seed=seed))
    return folder


def prompted_object_sizes(capture) -> dict:
    """{name: largest extent of the ground-truth mesh} of the objects prompts.json prompts."""
    from fignetctl.core.obj import read_obj

    names = [o["name"] for o in json.loads((capture / "prompts.json").read_text())["objects"]]
    sizes = {}
    for name in names:
        mesh = read_obj(capture / "ground_truth" / "objects" / f"{name}.obj")
        vertices = np.asarray(mesh[0] if isinstance(mesh, tuple) else mesh.vertices)
        extent = vertices.max(0) - vertices.min(0)
        sizes[name] = {"largest_extent": float(extent.max()), "extent": extent.round(4).tolist()}
    return sizes


def fit(capture, cameras, region, args, out_dir):
    from fignetctl.stages import fit_nerf

    torch.set_num_threads(args.threads)
    settings = fit_nerf.Settings(
        preset=args.preset,
        steps=args.steps,
        region=region,
        prompts=str(capture / "prompts.json"),
        seed=args.seed,
        device=args.device,
    )
    path = out_dir / f"nerf-{region.replace(':', '-').replace(',', '_')}.pt"
    started, cpu = time.perf_counter(), time.process_time()
    summary = fit_nerf.run(capture / "images", cameras, path, settings, overwrite=True)
    summary["wall_seconds"] = time.perf_counter() - started
    summary["cpu_seconds"] = time.process_time() - cpu  # training and evaluation, all threads
    print(f"  {region}: {summary['message']}", flush=True)
    return path, summary


def compared_box(capture, cameras):
    """The box --region prompts fits on this capture (the default preset's scene box)."""
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.config import preset_config
    from fignetctl.core.nerf.rays import scene_bounds
    from fignetctl.core.nerf.region import parse_region, resolve_region

    camera_set = read_cameras(cameras)
    bounds = scene_bounds(camera_set.points, camera_set.c2w, preset_config("fast").bounds_margin)
    return resolve_region(parse_region("prompts", capture / "prompts.json"), camera_set, bounds)


def region_psnr(path, capture, cameras, box):
    """Held-out PSNR of the field at `path` on the pixels whose rays pass through `box`."""
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.data import load_views
    from fignetctl.core.nerf.evaluation import evaluate_views
    from fignetctl.core.nerf.io import load_nerf

    model = load_nerf(path)
    views = load_views(capture / "images", read_cameras(cameras), model.config.max_image_side)
    result, _ = evaluate_views(model, views, model.inputs["held_out_views"], region=box)
    shares = [v["region_pixels"] for v in result["per_view"]]
    return result["region_psnr"], float(np.mean(shares))


def extract_objects(capture, cameras, nerf, out_dir, max_voxel=None) -> dict:
    """extract-mesh (defaults, threshold auto; `max_voxel` if given) of every prompted object
    from `nerf`: its summary
    figures and its mesh against the ground truth (Chamfer as a fraction of the object's
    largest side), as benchmarks/bench_extract_mesh.py measures them."""
    import sys

    import trimesh

    from fignetctl.core.obj import read_obj
    from fignetctl.errors import FignetError
    from fignetctl.stages import extract_mesh

    sys.path.insert(0, str(ROOT))
    from benchmarks.bench_extract_mesh import mesh_errors

    names = [o["name"] for o in json.loads((capture / "prompts.json").read_text())["objects"]]
    result = {}
    for name in names:
        folder = out_dir / f"{Path(nerf).stem}-{name}"
        settings = extract_mesh.Settings(object=name, device="cpu")
        if max_voxel is not None:
            settings = dataclasses.replace(settings, max_voxel=max_voxel)
        try:
            summary = extract_mesh.run(
                str(nerf),
                str(folder),
                settings,
                cameras=str(cameras),
                images=str(capture / "images"),
                prompts=str(capture / "prompts.json"),
            )
        except FignetError as error:  # a refusal is a result here
            result[name] = {"error": f"{type(error).__name__}: {error}"}
            continue
        mesh = trimesh.Trimesh(*read_obj(folder / "object.obj"))  # in the object frame: at its origin
        mesh.apply_translation(np.load(folder / "volume.npz")["origin"])
        truth = trimesh.Trimesh(*read_obj(capture / "ground_truth" / "objects" / f"{name}.obj"))
        chamfer, volume_iou = mesh_errors(mesh, truth)
        result[name] = {
            "object_size": summary.get("object_size"),
            "true_size": truth.extents.round(4).tolist(),
            "mask_iou": summary.get("mask_iou"),
            "threshold": summary.get("threshold"),
            "chamfer_fraction": chamfer,
            "volume_iou": volume_iou,
            "message": summary.get("message"),
        }
        print(
            f"    {Path(nerf).name} {name}: Chamfer {100 * chamfer:.1f} %; {summary.get('message')}",
            flush=True,
        )
    return result


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--capture", help="a capture folder (render-views); default: render the bundled one")
    parser.add_argument("--capture-seed", type=int, default=0)
    parser.add_argument("--cameras", help="cameras.npz; default: the capture's ground truth")
    parser.add_argument("--regions", nargs="+", default=["scene", "prompts"])
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2, help="torch threads per fit")
    parser.add_argument(
        "--parallel",
        action="store_true",
        help="run the fits side by side (one process each), so a shared machine loads them alike",
    )
    parser.add_argument(
        "--extract-mesh", action="store_true", help="also extract every prompted object from each fit"
    )
    parser.add_argument(
        "--extract-from",
        nargs="+",
        metavar="REGION=NERF",
        help="only extract the objects from these fitted files (e.g. scene=a.pt prompts=b.pt)",
    )
    parser.add_argument(
        "--max-voxel", type=float, default=None, help="extract-mesh's --max-voxel (default: its own)"
    )
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "nerf_region.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    capture = capture_folder(args.capture, args.capture_seed)
    cameras = Path(args.cameras) if args.cameras else capture / "ground_truth" / "cameras.npz"
    sizes = prompted_object_sizes(capture)
    smallest = min(s["largest_extent"] for s in sizes.values())
    out_dir = Path(tempfile.mkdtemp(prefix="bench-nerf-region-fits-"))
    print(f"capture {capture}; prompted objects {sizes}", flush=True)
    if args.extract_from:
        files = dict(item.split("=", 1) for item in args.extract_from)
        meshes = {
            region: extract_objects(capture, cameras, Path(nerf), out_dir, args.max_voxel)
            for region, nerf in files.items()
        }
        out = Path(args.out)
        report = json.loads(out.read_text()) if out.exists() else {}
        if all(region in report.get("runs", {}) for region in meshes):
            # the fits' figures stay; their meshes are replaced
            for region, found in meshes.items():
                report["runs"][region]["meshes"] = found
        else:
            report = {"capture": str(capture), "nerfs": files, "meshes": meshes}
        write_json(out, report, default=str)
        print(f"wrote {args.out}")
        return
    runs, paths = {}, {}
    if args.parallel:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(len(args.regions)) as pool:
            futures = {r: pool.submit(fit, capture, cameras, r, args, out_dir) for r in args.regions}
            fits = {r: f.result() for r, f in futures.items()}
    else:
        fits = {r: fit(capture, cameras, r, args, out_dir) for r in args.regions}
    for region in args.regions:
        paths[region], summary = fits[region]
        runs[region] = {
            key: summary.get(key)
            for key in (
                "train_seconds",
                "wall_seconds",
                "cpu_seconds",
                "held_out_psnr",
                "held_out_region_psnr",
                "voxel_size",
                "background_voxel_size",
                "region",
                "occupied_fraction",
                "region_occupied_fraction",
                "message",
            )
        }
        runs[region]["smallest_object_over_voxel"] = smallest / summary["voxel_size"]
    # every run's PSNR on the same pixels: those whose rays pass through the prompts region
    box = compared_box(capture, cameras)
    for region in args.regions:
        psnr_value, share = region_psnr(paths[region], capture, cameras, box)
        runs[region]["psnr_on_compared_pixels"] = psnr_value
        runs[region]["compared_pixel_share"] = share
        if args.extract_mesh:
            runs[region]["meshes"] = extract_objects(capture, cameras, paths[region], out_dir, args.max_voxel)
    result = {
        "capture": str(capture),
        "cameras": str(cameras),
        "preset": args.preset,
        "steps": args.steps,
        "prompted_objects": sizes,
        "smallest_object": smallest,
        "compared_region": box.tolist(),
        "runs": runs,
        "machine": {
            "platform": platform.platform(),
            "threads": args.threads,
            "device": args.device,
            "torch": torch.__version__,
        },
    }
    print(
        f"{'region':>18} {'train s':>8} {'CPU s':>7} {'PSNR':>7} {'region PSNR':>12} {'voxel mm':>9} {'outside mm':>10} "
        f"{'object/voxel':>12}"
    )
    for region, run in runs.items():
        print(
            f"{region:>18} {run['train_seconds']:8.0f} {run['cpu_seconds']:7.0f} {run['held_out_psnr']:7.2f} "
            f"{run.get('psnr_on_compared_pixels', float('nan')):12.2f} {1000 * run['voxel_size']:9.2f} "
            f"{1000 * run['background_voxel_size']:10.2f} {run['smallest_object_over_voxel']:12.1f}"
        )
    write_json(args.out, result, default=str)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
