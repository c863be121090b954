"""Physics ceilings: PyBullet restarted every frame from what a model is given at frame t.

Two states (fignetctl/core/ceilings.py): `finite-difference` (the rolled-out poses of frames t-1
and t give the velocity) and `velocity` (the rolled-out pose and instantaneous velocity), both
from frames 0-1 of the ground truth, rebuilt from the file's generator config. Reports, per
horizon (50 steps and 0.1, 0.2, 0.33, 0.5, 1.0, 1.67 s), the translation RMSE over all dynamic
objects, and the mean and RMS rotation error. `fresh` restarts each frame in a new PyBullet
world (the ceiling); `kept` resets the bodies in one world per rollout, so PyBullet's contact
manifolds carry over between frames (a reference: not a restart from the model's information).

With --nudges M ... it also runs PyBullet freely (no restarts) from frame 1 with every dynamic
object moved M metres in a random direction (`evaluate_nudged`): how far the scenes' own chaos
carries an error of that size at one frame. --worlds with no value runs only these.

    python benchmarks/physics_ceilings.py data/movi-b-test.h5 \
        -o benchmarks/results/physics-ceilings-movi-b.json
    python benchmarks/physics_ceilings.py data/movi-b-test.h5 --worlds --nudges 0 0.0001 0.001 0.003 0.01 \
        -o benchmarks/results/physics-nudged-movi-b.json
"""

from __future__ import annotations

import argparse
import sys
import time

from fignetctl import __version__
from fignetctl.core.atomic import write_json
from fignetctl.core.ceilings import (
    PAPER_STEPS,
    SECONDS_HORIZONS,
    evaluate_ceilings,
    evaluate_nudged,
    horizon_steps,
)
from fignetctl.core.provenance import file_sha256
from fignetctl.core.trajectory import read_trajectories

WORLDS = {"fresh": False, "kept": True}


def markdown_table(result: dict, key: str = "states", column: str = "state") -> str:
    """One row per state (or nudge) and horizon."""
    lines = [
        f"| {column} | steps | time (s) | translation RMSE (m) | rotation mean (°) | rotation RMS (°) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for state, rows in result[key].items():
        for row in rows:
            lines.append(
                f"| {state} | {row['steps']} | {row['seconds']:.3f} | {row['translation_rmse_m']:.4g} "
                f"| {row['rotation_mean_deg']:.3g} | {row['rotation_rms_deg']:.3g} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("data", help="a trajectory file written by make-dataset")
    parser.add_argument("-n", "--trajectories", type=int, default=None, help="the first n (default: all)")
    parser.add_argument("--steps", type=int, nargs="*", default=[PAPER_STEPS], help="horizons in steps")
    parser.add_argument(
        "--seconds", type=float, nargs="*", default=list(SECONDS_HORIZONS), help="horizons in s"
    )
    parser.add_argument("--worlds", nargs="*", choices=list(WORLDS), default=list(WORLDS))
    parser.add_argument(
        "--nudges", type=float, nargs="*", default=[], help="metres: also the free runs nudged by each"
    )
    parser.add_argument("--seed", type=int, default=0, help="of the nudges' directions")
    parser.add_argument("-o", "--output", required=True, help="json to write")
    args = parser.parse_args()
    if not args.worlds and not args.nudges:
        sys.exit("nothing to measure: give --worlds, or --nudges")
    if args.nudges and min(args.nudges) < 0:
        sys.exit(f"--nudges: distances >= 0 m, got {args.nudges}")
    data = read_trajectories(args.data)
    keys = list(data.trajectories)[: args.trajectories]
    shortest = min(data.trajectories[key].num_frames for key in keys)
    horizons = horizon_steps(data.dt, shortest, args.seconds, args.steps)
    output = {
        "command": " ".join(["python", *sys.argv]),
        "version": __version__,
        "data": args.data,
        "data_sha256": file_sha256(args.data),
        "horizons": horizons,
    }
    for world in args.worlds:
        started = time.perf_counter()
        result = evaluate_ceilings(data, horizons, args.trajectories, keep_world=WORLDS[world])
        result["seconds"] = round(time.perf_counter() - started, 1)
        output[f"{world}_world"] = result
        print(
            f"\n{world} world: {result['trajectories']} trajectories, {result['objects']} objects, "
            f"{result['seconds']} s\n\n{markdown_table(result)}",
            flush=True,
        )
    if args.nudges:
        started = time.perf_counter()
        result = evaluate_nudged(data, horizons, args.trajectories, args.nudges, args.seed)
        result["seconds"] = round(time.perf_counter() - started, 1)
        output["nudged_free_runs"] = result
        print(
            f"\nfree runs nudged at frame 1: {result['trajectories']} trajectories, {result['objects']} "
            f"objects, {result['seconds']} s\n\n{markdown_table(result, 'nudges', 'nudge')}",
            flush=True,
        )
    write_json(args.output, output)
    print(args.output)


if __name__ == "__main__":
    main()
