"""What a radiance field's accuracy costs in time: held-out PSNR against seconds of training.

For each preset, fits a field to the bundled capture (`fignetctl render-views`) with its
ground-truth cameras, evaluating the held-out views (every 8th) at intervals; the evaluation
time is not counted as training time. Records PSNR and the median z-depth error of held-out
pixels against ground_truth/depth.npz (absolute, and as % of the scene's size: the diagonal
of the sparse points' box), the final figures and the wall time.

    python benchmarks/bench_nerf.py                 # both presets (tens of minutes on 2 cores)
    python benchmarks/bench_nerf.py --quick         # fast preset, 300 steps (a few minutes)
    python benchmarks/bench_nerf.py --capture DIR   # an existing capture folder

Writes benchmarks/results/nerf_psnr_vs_time.json, docs/images/nerf-psnr-vs-time.png and
docs/images/nerf-held-out.png (rendered held-out views against the images, and depth).
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


def capture_folder(path):
    if path is not None:
        return Path(path)
    from fignetctl.core.synthetic_capture import capture_settings
    from fignetctl.stages.render_views import write_capture

    folder = Path(tempfile.mkdtemp(prefix="bench-nerf-")) / "capture"
    write_capture(folder, capture_settings(video=False))
    return folder


def ground_truth_depth(capture, views):
    import cv2

    depth = np.load(capture / "ground_truth" / "depth.npz")["depth"]
    size = (views.cameras.width, views.cameras.height)
    return np.stack([cv2.resize(d, size, interpolation=cv2.INTER_NEAREST) for d in depth])


def fit_preset(capture, preset, steps, evaluations):
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.config import preset_config
    from fignetctl.core.nerf.training import make_trainer

    started = time.perf_counter()
    cameras = read_cameras(capture / "ground_truth" / "cameras.npz")
    config = preset_config(preset, steps=steps)
    trainer = make_trainer(capture / "images", cameras, config)
    truth = ground_truth_depth(capture, trainer.views)
    points = cameras.points
    scene_size = float(np.linalg.norm(points.max(0) - points.min(0)))
    curve, renderings = [], None
    checkpoints = sorted({max(1, int(round(steps * k / evaluations))) for k in range(1, evaluations + 1)})
    for until in checkpoints:
        trainer.run(until_step=until)
        trainer.model.refresh_occupancy()
        result, renderings = trainer.evaluate(truth)
        depth_error = result.get("depth_median_abs_error", float("nan"))
        curve.append(
            {
                "step": trainer.step,
                "train_seconds": round(trainer.seconds, 2),
                "held_out_psnr": round(result["psnr"], 3),
                "depth_median_abs_error_m": depth_error,
                "depth_error_percent_of_scene": 100 * depth_error / scene_size,
                "occupied_fraction": round(trainer.model.occupancy.fraction, 4),
            }
        )
        print(preset, curve[-1], flush=True)
    summary = {
        "preset": preset,
        "config": dataclasses.asdict(config),
        "steps": steps,
        "image_size": [trainer.views.cameras.width, trainer.views.cameras.height],
        "train_views": len(trainer.train_views),
        "held_out_views": [int(i) for i in trainer.held_out_views],
        "scene_size_m": scene_size,
        "final": curve[-1],
        "wall_seconds": round(time.perf_counter() - started, 1),
        "curve": curve,
    }
    return summary, trainer, renderings, truth


def plot_curves(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for result in results:
        seconds = [p["train_seconds"] for p in result["curve"]]
        label = f'{result["preset"]} ({result.get("threads", 2)} thread{"s" if result.get("threads", 2) > 1 else ""})'
        axes[0].plot(seconds, [p["held_out_psnr"] for p in result["curve"]], "o-", label=label)
        axes[1].plot(seconds, [p["depth_error_percent_of_scene"] for p in result["curve"]], "o-", label=label)
    axes[0].axhline(25, color="grey", ls=":", lw=1)
    axes[0].set(
        xlabel="training time (s, CPU)", ylabel="held-out PSNR (dB)", title="fit-nerf on the bundled capture"
    )
    axes[1].set(xlabel="training time (s, CPU)", ylabel="median |depth error| (% of scene)", yscale="log")
    for axis in axes:
        axis.legend()
        axis.grid(alpha=0.3)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=90)


def views_picture(trainer, renderings, truth, path):
    """Rows: held-out views; columns: image, rendered, GT depth, rendered depth."""
    import cv2

    from fignetctl.core.nerf.visualize import colourise_depth, write_png

    rows = []
    for index, rendering in list(zip(trainer.held_out_views, renderings))[:3]:
        valid = truth[index][truth[index] > 0]
        low, high = np.percentile(valid, 1), np.percentile(valid, 99)
        rows.append(
            np.concatenate(
                [
                    (trainer.views.images[index] * 255).astype(np.uint8),
                    (np.clip(rendering.rgb, 0, 1) * 255).astype(np.uint8),
                    colourise_depth(truth[index], low, high),
                    colourise_depth(rendering.depth, low, high),
                ],
                axis=1,
            )
        )
    picture = np.concatenate(rows, axis=0)
    if picture.shape[1] > 1400:
        scale = 1400 / picture.shape[1]
        picture = cv2.resize(picture, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    write_png(path, picture)


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--capture", default=None, help="capture folder (default: render one to a temporary folder)"
    )
    parser.add_argument("--quick", action="store_true", help="fast preset only, 300 steps")
    parser.add_argument("--presets", default="fast,quality")
    parser.add_argument("--evaluations", type=int, default=6, help="held-out evaluations per preset")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "nerf_psnr_vs_time.json"))
    parser.add_argument("--plot", default=str(ROOT / "docs" / "images" / "nerf-psnr-vs-time.png"))
    parser.add_argument("--views-picture", default=str(ROOT / "docs" / "images" / "nerf-held-out.png"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from fignetctl.core.nerf.config import PRESETS

    capture = capture_folder(args.capture)
    presets = ["fast"] if args.quick else args.presets.split(",")
    results = []
    for preset in presets:
        steps = 300 if args.quick else PRESETS[preset].steps
        summary, trainer, renderings, truth = fit_preset(capture, preset, steps, args.evaluations)
        summary["threads"] = args.threads
        results.append(summary)
        views_picture(trainer, renderings, truth, Path(args.views_picture))
    previous = json.loads(Path(args.out).read_text()) if Path(args.out).exists() and not args.quick else {}
    if (
        previous.get("quick") is False
    ):  # keep the presets this run did not fit (one preset per run fits an idle hour)
        results = [r for r in previous["results"] if r["preset"] not in presets] + results
    results.sort(key=lambda r: list(PRESETS).index(r["preset"]))
    document = {
        "machine": f"{platform.processor() or platform.machine()}, torch {torch.__version__}",
        "capture": str(capture),
        "quick": args.quick,
        "results": results,
    }
    write_json(args.out, document)
    plot_curves(results, Path(args.plot))
    print(args.out, args.plot, args.views_picture)


if __name__ == "__main__":
    main()
