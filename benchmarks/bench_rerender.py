"""Time per re-rendered frame against an unedited render, on a NeRF of the bundled capture.

Builds the inputs `rerender` needs from the capture's ground truth (extract-mesh and a learned
rollout are other stages): volume.npz = the ball's ground-truth box grown by 1 cm, and a
scripted rollout.h5 in which the ball hops out of the tray onto the table, rolling. Then, for
one camera, it times (median of --repeats): the unedited render of every pixel; a re-rendered
frame (only the pixels whose rays meet V_o or R_t·V_o, bent); and the same frame with every
pixel bent (no background reuse). Prints the figures, writes json, and a strip of frames.

    fignetctl render-views -o /tmp/cap --views 24 --width 160 --height 120 --no-video
    (fit a nerf.pt on /tmp/cap/images with the fast preset)
    .venv/bin/python benchmarks/bench_rerender.py --capture /tmp/cap --nerf nerf.pt --strip docs/images/rerender-strip.png
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from fignetctl.core import rerender
from fignetctl.core.atomic import write_json
from fignetctl.core.cameras import read_cameras
from fignetctl.core.nerf import load_nerf
from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile, write_trajectories
from fignetctl.core.transforms import quat_from_axis_angle
from fignetctl.core.volume import Volume, write_volume

DEFAULT_OUT = Path(__file__).parent / "results" / "rerender.json"


def ball_inputs(capture: Path, folder: Path, frames: int = 16, dt: float = 1 / 30):
    """volume.npz and a scripted rollout.h5 of the capture's ball (ground truth)."""
    import trimesh

    scene = json.loads((capture / "ground_truth" / "scene.json").read_text())
    ball = next(o for o in scene["objects"] if o["name"] == "ball")
    lower, upper = np.array(ball["bounds"], np.float64)
    origin = 0.5 * (lower + upper)
    volume = Volume(
        lower - [0.01, 0.01, 0.0], upper + 0.01, origin, lower - [0.3, 0.3, 0.1], upper + [0.3, 0.3, 0.0]
    )
    write_volume(folder / "volume.npz", volume)
    mesh = trimesh.load(capture / "ground_truth" / "objects" / "ball.obj", force="mesh")
    times = np.arange(frames) * dt
    radius = 0.5 * (upper[2] - lower[2])
    z = np.maximum(origin[2] + 2.0 * times - 5.0 * times**2, radius + 0.0)  # hop, then on the table
    positions = np.stack([origin[0] + 0.1 * times, origin[1] + 0.75 * times, z], -1)
    quaternions = quat_from_axis_angle(np.tile([1.0, 0, 0], (frames, 1)), -0.75 / radius * times)
    trajectory = Trajectory(
        mesh_names=np.array(["ball"], dtype=object),
        scales=np.ones(1, np.float32),
        positions=positions[:, None].astype(np.float32),
        quaternions=quaternions[:, None].astype(np.float32),
        static=np.array([False]),
        mass=np.array([1e-3], np.float32),
        friction=np.array([0.5], np.float32),
        restitution=np.array([0.5], np.float32),
    )
    meshes = {"ball": Mesh(np.asarray(mesh.vertices - origin, np.float32), np.asarray(mesh.faces, np.int32))}
    write_trajectories(
        folder / "rollout.h5", TrajectoryFile(dt, np.array([0, 0, -10.0]), meshes, {"00000": trajectory})
    )
    return volume, rerender.object_motion(
        TrajectoryFile(dt, np.array([0, 0, -10.0]), meshes, {"00000": trajectory}), volume
    )


def median_seconds(function, repeats):
    durations = []
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        durations.append(time.perf_counter() - started)
    return statistics.median(durations)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--capture", type=Path, required=True)
    parser.add_argument("--nerf", type=Path, required=True)
    parser.add_argument("--camera", type=int, default=0)
    parser.add_argument("--mode", default="duplicate", choices=rerender.MODES)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--strip", type=Path, default=None, help="PNG: a strip of frames")
    parser.add_argument("--work", type=Path, default=Path("/tmp/bench_rerender"))
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    volume, motion = ball_inputs(args.capture, args.work)
    cameras = read_cameras(args.capture / "ground_truth" / "cameras.npz")
    camera = cameras.camera(args.camera)
    model = load_nerf(args.nerf)
    renderer = rerender.Rerenderer(model, volume, motion, args.mode)
    origins, directions = camera.rays()
    unedited = median_seconds(lambda: rerender.render_rays(model, origins, directions), args.repeats)
    renderer.background(camera)
    steps = list(range(0, len(motion), max(1, len(motion) // 4)))
    per_frame, all_bent, fractions = [], [], []
    for step in steps:
        per_frame.append(median_seconds(lambda: renderer.render(camera, step), args.repeats))
        fractions.append(float(renderer.render(camera, step).bent.mean()))
        warp = rerender.make_warp(motion, step, volume, args.mode)
        box = rerender.bending_box(model, motion, step, volume)
        all_bent.append(
            median_seconds(lambda: rerender.render_rays(model, origins, directions, warp, box), args.repeats)
        )
    result = {
        "image": f"{cameras.width}x{cameras.height}",
        "mode": args.mode,
        "frames_timed": len(steps),
        "unedited_ms": 1000 * unedited,
        "rerendered_frame_ms": 1000 * statistics.mean(per_frame),
        "every_pixel_bent_ms": 1000 * statistics.mean(all_bent),
        "bent_pixel_fraction": statistics.mean(fractions),
        "nerf_held_out_psnr": model.metrics.get("held_out_psnr"),
        "machine": f"{platform.processor() or platform.machine()}, torch CPU threads {__import__('torch').get_num_threads()}",
    }
    for key, value in result.items():
        print(f"{key:24s} {value:.4g}" if isinstance(value, float) else f"{key:24s} {value}")
    write_json(args.out, result)
    if args.strip:
        write_strip(renderer, camera, motion, args.strip)


def write_strip(renderer, camera, motion, path, count=5):
    """Frames at `count` evenly spaced steps, side by side, the path traced."""
    import cv2

    steps = np.linspace(0, len(motion) - 1, count).round().astype(int)
    tiles = []
    for step in steps:
        image = rerender.to_uint8(renderer.render(camera, int(step)).rgb)
        rerender.draw_trace(image, camera, motion.positions[: step + 1])
        tiles.append(np.pad(image, ((0, 0), (0, 2), (0, 0)), constant_values=255))
    cv2.imwrite(str(path), cv2.cvtColor(np.concatenate(tiles, axis=1), cv2.COLOR_RGB2BGR))


if __name__ == "__main__":
    main()
