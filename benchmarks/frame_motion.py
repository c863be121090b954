"""Where in a trajectory file the one-step targets' weight lies: each frame's change of motion
beyond gravity (`training.frame_motion`, the measure `train --frame-sampling motion` draws
by), squared and summed, and what share of it the busiest frames and the first frames hold;
with the spread of the loss weights that 'motion' sampling gives.

    python benchmarks/frame_motion.py data/movi-b-train.h5 -n 300 \
        -o benchmarks/results/frame-motion-movi-b-train.json
"""

from __future__ import annotations

import argparse
import json

import h5py
import numpy as np

from fignetctl.core.atomic import write_json
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.training import FrameSampler, frame_motion, simulator_config_for
from fignetctl.core.trajectory import read_trajectories


def motion_shares(motions, energy_shares=(0.5, 0.8, 0.9, 0.99), first_frames=30) -> dict:
    """From each trajectory's `frame_motion` (list of (T − 2,)): the fraction of all frames that
    holds each share of the summed squares (the busiest first), and the share of the first
    `first_frames` frames of each trajectory (frames t = 1 … first_frames)."""
    energy = np.concatenate([m**2 for m in motions])
    ordered = np.cumsum(np.sort(energy)[::-1]) / energy.sum()
    first = np.concatenate([np.arange(len(m)) < first_frames for m in motions])
    return {
        "frames": len(energy),
        "fraction_of_frames_holding": {
            str(share): float((np.searchsorted(ordered, share) + 1) / len(energy)) for share in energy_shares
        },
        f"first_{first_frames}_frames": {
            "fraction_of_frames": float(first.mean()),
            "share": float(energy[first].sum() / energy.sum()),
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("data", help="a trajectory file")
    parser.add_argument("-n", "--trajectories", type=int, default=300, help="the first n")
    parser.add_argument("-o", "--output", default=None, help="json to write")
    args = parser.parse_args()
    with h5py.File(args.data, "r") as f:
        keys = sorted(f["trajectories"])[: args.trajectories]
    data = read_trajectories(args.data, keys)
    config = simulator_config_for("fignet-star", "small", 0.2, 256, state="velocities")
    scenes = scenes_from_data(data, config, TRAINING_STATIC_REACH)
    results = {"data": args.data, "trajectories": len(scenes)}
    results.update(motion_shares([frame_motion(scene, data.gravity) for scene in scenes]))
    weights = FrameSampler(scenes, "motion", data.gravity).weights
    results["motion_sampling_weights"] = {
        "min": float(weights.min()),
        "median": float(np.median(weights)),
        "max": float(weights.max()),
    }
    print(json.dumps(results, indent=1))
    if args.output:
        write_json(args.output, results)
        print(args.output)


if __name__ == "__main__":
    main()
