"""Benchmark of `fignetctl capture-poses` on the bundled capture (fignetctl.core.synthetic_capture).

Renders the capture at its defaults (or reuses --capture DIR), runs capture-poses on its
still images and on its video (through the CLI, as a user would), and compares the result
with the ground-truth cameras:

- registered / total images;
- camera centre error after a similarity (Umeyama) alignment of the estimated centres onto
  the true ones: mean and max, in mm and as % of the scene size (the diagonal of
  scene.json's bounds, the box everything lies in);
- rotation error after that alignment: the angle of R_true⁻¹ · R_align · R_estimated, degrees;
- table tilt: the angle between capture-poses' z axis and the true up (the table top is the
  true z = 0 plane), degrees; and the height of capture-poses' z = 0 in the true frame, mm;
- scale error |s − 1| of that similarity, with --camera-height set to the true mean camera
  height above the table (what a user would measure), and with the default 0.5 m;
- wall time of the command.

Video frames are compared with the true camera at their fractional orbit step
(frame f is at view f / video_step: capture.ring_cameras).

    .venv/bin/python benchmarks/bench_capture_poses.py --out benchmarks/results/capture_poses.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fignetctl.core import synthetic_capture as capture_module
from fignetctl.core.atomic import write_json
from fignetctl.core.cameras import read_cameras
from fignetctl.core.world_alignment import umeyama

DEFAULT_OUT = Path(__file__).parent / "results" / "capture_poses.json"
FIGNETCTL = [str(Path(sys.executable).parent / "fignetctl")]


def rotation_angle_deg(rotations) -> np.ndarray:
    """(n,) angle of each (n, 3, 3) rotation, degrees."""
    cosine = (np.trace(rotations, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(cosine, -1, 1)))


def compare(estimated, truth_c2w: np.ndarray, scene_size: float, true_focal: float) -> dict:
    """Errors of estimated cameras against true c2w (same order) after a similarity fit."""
    scale, rotation, translation = umeyama(estimated.centres, truth_c2w[:, :3, 3])
    moved = scale * estimated.centres @ rotation.T + translation
    centre_error = np.linalg.norm(moved - truth_c2w[:, :3, 3], axis=1)
    relative = np.einsum("nji,jk,nkl->nil", truth_c2w[:, :3, :3], rotation, estimated.c2w[:, :3, :3])
    rotation_error = rotation_angle_deg(relative)
    up = rotation @ [0.0, 0.0, 1.0]
    # The rotation that best aligns the orientations themselves (not the centres): what is left
    # is the orientations' own error, free of the centre fit's.
    u, _, vt = np.linalg.svd(np.einsum("nij,nkj->ik", truth_c2w[:, :3, :3], estimated.c2w[:, :3, :3]))
    best = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    best_fit_error = rotation_angle_deg(
        np.einsum("nji,jk,nkl->nil", truth_c2w[:, :3, :3], best, estimated.c2w[:, :3, :3])
    )
    return {
        "centre_error_mean_mm": 1000 * float(centre_error.mean()),
        "centre_error_max_mm": 1000 * float(centre_error.max()),
        "centre_error_mean_pct_scene": 100 * float(centre_error.mean()) / scene_size,
        "centre_error_max_pct_scene": 100 * float(centre_error.max()) / scene_size,
        "rotation_error_mean_deg": float(rotation_error.mean()),
        "rotation_error_max_deg": float(rotation_error.max()),
        "rotation_error_best_fit_mean_deg": float(best_fit_error.mean()),
        "rotation_error_best_fit_max_deg": float(best_fit_error.max()),
        "focal_error_pct": 100 * float(np.abs(estimated.K[:, 0, 0] / true_focal - 1).max()),
        "table_tilt_deg": float(np.degrees(np.arccos(np.clip(up[2], -1, 1)))),
        "table_height_error_mm": 1000 * float(translation[2]),
        "scale_error_pct": 100 * abs(float(scale) - 1.0),
    }


def run_capture_poses(args: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    result = subprocess.run([*FIGNETCTL, "capture-poses", *args], capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if result.returncode != 0:
        raise CommandFailed(seconds, result.stderr.strip().splitlines()[-1])
    return seconds, result.stderr.strip().splitlines()[-1]


class CommandFailed(Exception):
    """capture-poses exited with an error: (seconds, its one-line message)."""


def true_mean_camera_height(truth) -> float:
    return float(truth.centres[:, 2].mean())  # the table top is z = 0


def bench_images(
    capture: Path, work: Path, truth, scene_size: float, height: float | None, plot_path=None
) -> dict:
    output = work / f"images-{height}" / "cameras.npz"
    args = ["--images", str(capture / "images"), "-o", str(output)]
    if height is not None:
        args += ["--camera-height", f"{height:.6f}"]
    seconds, summary = run_capture_poses(args)
    estimated = read_cameras(output)
    names = [str(n) for n in truth.image_names]
    order = [names.index(str(n)) for n in estimated.image_names]
    if plot_path is not None:
        plot(estimated, truth.c2w[order], plot_path)
    return {
        "input": "images",
        "camera_height_m": height,
        "registered": len(estimated),
        "total": len(truth),
        "sparse_points": len(estimated.points),
        "seconds": seconds,
        "summary": summary,
        **compare(estimated, truth.c2w[order], scene_size, truth.K[0, 0, 0]),
    }


def bench_video(
    capture: Path, work: Path, scene: dict, scene_size: float, height: float, every: int, matcher: str
) -> dict:
    from fignetctl.core.synthetic_capture import CaptureSettings, ring_cameras

    settings = scene["settings"]
    config = CaptureSettings(**{k: tuple(v) if isinstance(v, list) else v for k, v in settings.items()})
    output = work / f"video-{every}-{matcher}" / "cameras.npz"
    args = [
        "--video",
        str(capture / "video.mp4"),
        "--every",
        str(every),
        "--matcher",
        matcher,
        "-o",
        str(output),
        "--camera-height",
        f"{height:.6f}",
    ]
    seconds, summary = run_capture_poses(args)
    estimated = read_cameras(output)
    frames = np.array([int(Path(str(n)).stem.split("_")[1]) for n in estimated.image_names])
    total_frames = config.views * config.video_step
    picked = len(list((output.parent / "images").glob("*.png")))
    truth_c2w = ring_cameras(config, frames / config.video_step)["c2w"]
    return {
        "input": f"video --every {every} --matcher {matcher}",
        "camera_height_m": height,
        "registered": len(estimated),
        "total": picked,
        "video_frames": total_frames,
        "sparse_points": len(estimated.points),
        "seconds": seconds,
        "summary": summary,
        **compare(estimated, truth_c2w, scene_size, config_focal(config)),
    }


def config_focal(config) -> float:
    from fignetctl.core.synthetic_capture import intrinsics

    return float(intrinsics(config)[0, 0])


def plot(estimated, truth_c2w, path: Path) -> None:
    """Top and side views: true cameras, capture-poses' cameras and sparse points moved by the
    similarity fitted to the camera centres."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scale, rotation, translation = umeyama(estimated.centres, truth_c2w[:, :3, 3])
    centres = scale * estimated.centres @ rotation.T + translation
    points = scale * estimated.points @ rotation.T + translation
    figure, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for axis, (i, j, label) in zip(axes, [(0, 1, "top view (x, y)"), (0, 2, "side view (x, z)")]):
        axis.scatter(points[:, i], points[:, j], s=1, c=estimated.point_colors / 255.0, label="sparse points")
        axis.plot(truth_c2w[:, i, 3], truth_c2w[:, j, 3], "k.", ms=9, label="true cameras")
        axis.plot(centres[:, i], centres[:, j], "r+", ms=9, label="capture-poses")
        axis.set_title(label)
        axis.set_aspect("equal")
        axis.set_xlabel("m")
    axes[1].axhline(0.0, color="grey", lw=0.5)
    axes[0].legend(loc="upper right", fontsize=7)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def format_row(row: dict) -> str:
    if "error" in row:
        return f"{row['input']:<36} FAILED ({row['seconds']:.1f} s): {row['error']}"
    return (
        f"{row['input']:<36} {row['registered']:>3}/{row['total']:<3} "
        f"centre {row['centre_error_mean_pct_scene']:.3f}% mean / {row['centre_error_max_pct_scene']:.3f}% max "
        f"({row['centre_error_max_mm']:.1f} mm)  rot {row['rotation_error_mean_deg']:.2f}° / {row['rotation_error_max_deg']:.2f}° "
        f"(best fit {row['rotation_error_best_fit_mean_deg']:.2f}° / {row['rotation_error_best_fit_max_deg']:.2f}°)  "
        f"focal {row['focal_error_pct']:.1f}%  "
        f"tilt {row['table_tilt_deg']:.3f}°  z0 {row['table_height_error_mm']:+.1f} mm  "
        f"scale err {row['scale_error_pct']:.2f}%  {row['seconds']:.1f} s"
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--capture", type=Path, default=None, help="An existing render-views folder (default: render one)."
    )
    parser.add_argument(
        "--video-runs",
        nargs="+",
        default=["3:auto", "3:sequential", "6:auto"],
        help="EVERY:MATCHER pairs for the video runs.",
    )
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument(
        "--plot",
        type=Path,
        default=Path(__file__).parents[1] / "docs" / "images" / "capture-poses.png",
        help="Top and side views of the first run against the truth.",
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-capture-poses-") as tmp:
        tmp = Path(tmp)
        capture = args.capture
        render_seconds = None
        if capture is None:
            from fignetctl.stages.render_views import write_capture

            capture = tmp / "capture"
            start = time.perf_counter()
            write_capture(capture)  # the defaults
            render_seconds = time.perf_counter() - start
        truth = read_cameras(capture / "ground_truth" / "cameras.npz")
        scene = json.loads((capture / "ground_truth" / "scene.json").read_text())
        low, high = np.array(scene["bounds"], float)
        scene_size = float(np.linalg.norm(high - low))
        height = true_mean_camera_height(truth)
        rows = [
            bench_images(capture, tmp, truth, scene_size, height, args.plot),
            bench_images(capture, tmp, truth, scene_size, None),
        ]
        for run in args.video_runs:
            every, matcher = run.split(":")
            try:
                rows.append(bench_video(capture, tmp, scene, scene_size, height, int(every), matcher))
            except CommandFailed as failure:
                seconds, message = failure.args
                rows.append(
                    {
                        "input": f"video --every {every} --matcher {matcher}",
                        "error": message,
                        "seconds": seconds,
                    }
                )
    for row in rows:
        print(format_row(row))
    document = {
        "benchmark": "capture-poses on the bundled capture",
        "capture_settings": scene["settings"],
        "scene_size_m": scene_size,
        "true_mean_camera_height_m": height,
        "render_seconds": render_seconds,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "capture_module_sha256": hashlib.sha256(Path(capture_module.__file__).read_bytes()).hexdigest(),
        "goals": {
            "registered": "all",
            "centre_error_max_pct_scene": 1.0,
            "rotation_error_max_deg": 0.5,
            "table_tilt_deg": 2.0,
        },
        "rows": rows,
    }
    write_json(args.out, document)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
