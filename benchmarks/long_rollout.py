"""Long rollouts: do objects stay finite, above the floor and, once settled, settled?

Rolls a model out for --steps steps from frames 0-1 of test trajectories and reports, per
trajectory and overall: whether every pose stayed finite, the deepest penetration of any
dynamic vertex below the floor (z of the highest static vertex, the floor's top) beside the
recorded trajectory's own over the same frames (PyBullet's contacts give a little, and the model
sees decimated meshes), and how far objects moved over the last 50 steps (settled objects
should not drift), beside how far they moved in the recording over the same frames where it is
that long (`make-dataset --duration 7` covers 200 steps: balls roll on in PyBullet too).

Where the depth is made: the depth of the object that goes deepest (in the rollout, and in the
recording) is split over the steps that took it deeper than it had been, by how fast the object
came into each of them (its centre's speed over the step before, `depth_by_speed`): depth made
in a fast step is an impact the step does not stop, depth made below 0.1 m/s an object sinking
where it rests.

    python benchmarks/long_rollout.py --model fignetctl/assets/models/fignet-star-movi-b.pt \
        --data data/movi-b-test.h5 -n 10 --steps 200 --out docs/results/long-rollout.json
"""

import argparse
import dataclasses
import json

import numpy as np

from fignetctl.bench.options import add_rotations_option
from fignetctl.core.atomic import write_json
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.evaluation import lowest_object_z
from fignetctl.core.model.rollout import RolloutError, guards_for, rollout
from fignetctl.core.model.scene_data import DECIMATIONS, EVALUATION_STATIC_REACH, scene_from_trajectory
from fignetctl.core.trajectory import read_trajectories

SETTLE_WINDOW = 50

SPEED_BINS = (0.1, 0.5, 2.0)
"""m/s: the edges of the speed classes of `depth_by_speed` (below 0.1: resting or sinking;
above 2: falling or thrown)."""


def object_depths(scene, positions, quaternions, floor):
    """(T, O) depth of each object's lowest vertex below `floor` (0 above it; 0 for static ones)."""
    geometry = scene.geometry
    lowest = np.stack([lowest_object_z(geometry, p, q) for p, q in zip(positions, quaternions)])
    return np.where(geometry.static, 0.0, np.maximum(0.0, floor - lowest))


def speed_class(speed) -> str:
    """The `SPEED_BINS` class of a speed in m/s, as "lo-hi m/s"."""
    edges = (0.0, *SPEED_BINS, np.inf)
    k = int(np.searchsorted(SPEED_BINS, speed, side="right"))
    return f"{edges[k]:g}-{edges[k + 1]:g} m/s"


def depth_by_speed(depths, positions, dt) -> dict:
    """For the object of the largest depth in `depths` (T, O): its depth, the frame where it is
    reached, and that depth split by the `speed_class` of its centre over the step before each
    step that took it deeper than it had been (over the step itself for step 1; a depth it
    starts at is "at the start"). An object that rolls, its lowest vertex dipping in and out,
    adds only its new depths."""
    frame, deepest = np.unravel_index(int(np.argmax(depths)), depths.shape)
    speeds = np.linalg.norm(np.diff(positions[:, deepest], axis=0), axis=1) / dt  # [t - 1]: over step t
    record = np.maximum.accumulate(depths[: frame + 1, deepest])
    gained = {"at the start": float(record[0])} | {speed_class(s): 0.0 for s in (0.0, *SPEED_BINS)}
    for t in np.flatnonzero(np.diff(record) > 0) + 1:
        gained[speed_class(speeds[max(t - 2, 0)])] += float(record[t] - record[t - 1])
    return {
        "object": int(deepest),
        "depth_m": float(depths[frame, deepest]),
        "frame": int(frame),
        "depth_by_entry_speed_m": {k: round(v, 5) for k, v in gained.items()},
    }


def summed_depths(deepest) -> dict:
    """`depth_by_speed`'s depths summed over trajectories, per speed class."""
    classes = deepest[0]["depth_by_entry_speed_m"]
    return {k: round(sum(d["depth_by_entry_speed_m"][k] for d in deepest), 5) for k in classes}


def one_trajectory(simulator, scene, steps, **options):
    try:
        positions, quaternions = rollout(simulator, scene, steps, **options)
        finite = True
    except RolloutError as error:
        positions, quaternions, finite = error.positions, error.quaternions, False
    static_vertices = scene.geometry.static[scene.geometry.vertex_object]
    floor = scene.geometry.world_vertices(scene.positions[0], scene.quaternions[0])[static_vertices, 2].max()
    frames = len(positions)  # the recorded frames the rollout covers (all, when it is longer)
    depths = object_depths(scene, positions, quaternions, floor)
    recorded_poses = scene.positions[:frames], scene.quaternions[:frames]
    recorded_depths = object_depths(scene, *recorded_poses, floor)
    dynamic = ~scene.geometry.static
    window = min(SETTLE_WINDOW, frames)  # all of a shorter rollout
    drift = np.linalg.norm(positions[-1, dynamic] - positions[-window, dynamic], axis=1)
    row = {
        "trajectory": scene.name,
        "frames": frames,
        "finite": finite,
        "max_penetration_m": float(depths.max()),
        "recorded_max_penetration_m": float(recorded_depths.max()),
        "recorded_frames": len(recorded_depths),
        "drift_last_50_steps_m": drift.round(4).tolist(),
        "deepest": depth_by_speed(depths, positions, scene.dt),
        "recorded_deepest": depth_by_speed(recorded_depths, recorded_poses[0], scene.dt),
    }
    if len(scene.positions) >= frames:  # the recording covers the rollout
        recorded = scene.positions[frames - window : frames]
        row["recorded_drift_last_50_steps_m"] = (
            np.linalg.norm(recorded[-1, dynamic] - recorded[0, dynamic], axis=1).round(4).tolist()
        )
    return row


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("-n", type=int, default=10)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--free-flight", action="store_true", help="objects that touch nothing fly exactly")
    parser.add_argument(
        "--keep-out", action="store_true", help="objects are moved back out of static meshes they pass into"
    )
    parser.add_argument("--sleep", action="store_true", help="objects that have come to rest sleep")
    parser.add_argument(
        "--decimation",
        choices=DECIMATIONS,
        help="decimate the meshes so instead of as the model file says (the model then sees meshes unlike "
        "those it was trained on; for the recordings' depth under either)",
    )
    parser.add_argument(
        "--max-faces",
        type=int,
        help="decimate the meshes to at most this many faces instead of the model file's (0: keep them whole)",
    )
    add_rotations_option(parser)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    simulator = load_model(args.model, rotations=args.rotations)
    meshes = {"decimation": args.decimation or simulator.config.decimation}
    if args.max_faces is not None:
        meshes["max_faces_per_object"] = args.max_faces or None
    simulator.config = dataclasses.replace(simulator.config, **meshes)
    data = read_trajectories(args.data)
    options = {"guards": guards_for(data.dt, data.gravity, args.sleep, args.free_flight, args.keep_out)}
    cache = {}
    rows = []
    for key in list(data.trajectories)[: args.n]:
        scene = scene_from_trajectory(data, key, simulator.config, cache, EVALUATION_STATIC_REACH)
        rows.append(one_trajectory(simulator, scene, args.steps, **options))
        print(json.dumps(rows[-1]), flush=True)
    drifts = np.concatenate([r["drift_last_50_steps_m"] for r in rows])
    summary = {
        "all_finite": all(r["finite"] for r in rows),
        "max_penetration_m": max(r["max_penetration_m"] for r in rows),
        "recorded_max_penetration_m": max(r["recorded_max_penetration_m"] for r in rows),
        "trajectories_deeper_than_2cm": sum(r["max_penetration_m"] > 0.02 for r in rows),
        "recorded_trajectories_deeper_than_2cm": sum(r["recorded_max_penetration_m"] > 0.02 for r in rows),
        "deepest_depth_by_entry_speed_m": summed_depths([r["deepest"] for r in rows]),
        "recorded_deepest_depth_by_entry_speed_m": summed_depths([r["recorded_deepest"] for r in rows]),
        "median_drift_last_50_steps_m": float(np.median(drifts)),
        "fraction_objects_drift_below_1cm": float(np.mean(drifts < 0.01)),
    }
    if all("recorded_drift_last_50_steps_m" in r for r in rows):
        recorded = np.concatenate([r["recorded_drift_last_50_steps_m"] for r in rows])
        summary["recorded_median_drift_last_50_steps_m"] = float(np.median(recorded))
        summary["recorded_fraction_objects_drift_below_1cm"] = float(np.mean(recorded < 0.01))
    print(json.dumps(summary))
    write_json(
        args.out,
        {
            "model": args.model,
            "data": args.data,
            "steps": args.steps,
            "free_flight": args.free_flight,
            "keep_out": args.keep_out,
            "sleep": args.sleep,
            "rotations": simulator.rotations,
            "decimation": simulator.config.decimation,
            "max_faces": simulator.config.max_faces_per_object,
            "summary": summary,
            "trajectories": rows,
        },
    )


if __name__ == "__main__":
    main()
