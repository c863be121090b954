"""How much of the one-step target a trained model explains: the fraction of the target
variance it leaves unexplained (FVU; 1 for a model that predicts the mean, 0 for a perfect one)
on noise-free frames of trajectory files, e.g. held-out and training data side by side. Equal
figures on both mean the model underfits; a much lower training figure means it overfits.
The FVU is of what the network outputs, in its normalized units; `--rigid` adds the rigid FVU
of every frame (learnability.rigid_fraction_unexplained: the next pose and velocity after shape
matching, in metres per frame), the same measure whatever a model decodes (e.g. `--free-motion`
models, whose network outputs only the change from free motion).

    python benchmarks/one_step_fvu.py data/fignet-star-movi-b-velocities.pt \
        data/movi-b-test.h5 data/movi-b-train-4k.h5 -n 6 --frames 20 \
        -o docs/results/one-step-fvu-velocities.json
"""

from __future__ import annotations

import argparse

import h5py

from fignetctl.bench.options import add_rotations_option
from fignetctl.core.atomic import write_json
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.learnability import (
    fraction_unexplained,
    one_step_examples,
    rigid_fraction_unexplained,
)
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.trajectory import read_trajectories


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="a model file from `fignetctl train`")
    parser.add_argument("data", nargs="+", help="trajectory files")
    parser.add_argument("-n", "--trajectories", type=int, default=6, help="the first n of each file")
    parser.add_argument("--frames", type=int, default=20, help="frames per trajectory")
    add_rotations_option(parser)
    parser.add_argument(
        "--rigid", action="store_true", help="also the rigid FVU, over every frame of the n trajectories"
    )
    parser.add_argument("-o", "--output", default=None, help="json to write")
    args = parser.parse_args()
    simulator = load_model(args.model, rotations=args.rotations)
    results = {
        "model": args.model,
        "trajectories": args.trajectories,
        "frames": args.frames,
        "rotations": simulator.rotations,
        "files": {},
    }
    for path in args.data:
        with h5py.File(path, "r") as f:  # the ids alone, without reading a large file twice
            keys = sorted(f["trajectories"])[: args.trajectories]
        data = read_trajectories(path, keys)
        scenes = scenes_from_data(data, simulator.config, TRAINING_STATIC_REACH)
        figures = fraction_unexplained(
            simulator, one_step_examples(simulator, scenes, frames_per_scene=args.frames)
        )
        results["files"][path] = figures
        print(
            f"{path}: FVU {figures['all']:.3f} (position part {figures['position']:.3f}, "
            f"velocity part {figures.get('velocity', float('nan')):.3f}) over {figures['vertices']} vertices"
        )
        if args.rigid:
            figures["rigid"] = rigid_fraction_unexplained(simulator, scenes)
            print(
                f"{path}: rigid FVU {figures['rigid']['all']:.3f} (position part "
                f"{figures['rigid']['position']:.3f}, velocity part "
                f"{figures['rigid'].get('velocity', float('nan')):.3f}), every frame"
            )
    if args.output:
        write_json(args.output, results)
        print(args.output)


if __name__ == "__main__":
    main()
