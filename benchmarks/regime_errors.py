"""Where a model's one-step errors lie, in millimetres per frame: each dynamic vertex of every
noise-free frame of held-out trajectories is put in the regime its object is in over the
recorded step (free fall; at rest or sliding or rolling steadily; an impact, where its motion
changes by more than 5 g dt² beyond gravity; other contact) and the model's rigid next step
(the network alone) is compared with the recording there. Impacts carry most of the squared
error, so they are what an MSE loss fits; calm objects' small errors (and their bias, which
pulls a resting object into the floor) are what a rollout adds up over many frames. With
--radii, it also says, per regime, how many vertex-frames belong to an object with no face
within each radius of another object's (no face-face edge at that collision radius) and how
much of the squared error they carry: what a larger radius could reach. For a velocity-state
model it also gives, per regime, how much of the recorded change of each object's velocity and
spin over the step the network's step follows (`learnability.step_response`).

    python benchmarks/regime_errors.py benchmarks/results/velocity-continued-12665-more-steps/model.pt \
        data/movi-b-test.h5 -n 6 --radii 0.2 0.3 0.4 -o regimes.json
"""

from __future__ import annotations

import argparse

import h5py

from fignetctl.core.atomic import write_json
from fignetctl.core.model.checkpoint import load_checkpoint
from fignetctl.core.model.learnability import regime_errors
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.trajectory import read_trajectories


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="a model file from `fignetctl train`")
    parser.add_argument("data", help="a trajectory file (held-out)")
    parser.add_argument("-n", "--trajectories", type=int, default=6, help="its first n trajectories")
    parser.add_argument(
        "--radii", type=float, nargs="*", default=[], help="collision radii (m) to check the reach of"
    )
    parser.add_argument("-o", "--output", default=None, help="json to write")
    args = parser.parse_args()
    simulator = load_checkpoint(args.model)
    with h5py.File(args.data, "r") as f:
        keys = sorted(f["trajectories"])[: args.trajectories]
    scenes = scenes_from_data(read_trajectories(args.data, keys), simulator.config, TRAINING_STATIC_REACH)
    regimes = regime_errors(simulator, scenes, args.radii)
    last = "velocity" if simulator.config.uses_velocities else "position"
    print(f"{'regime':18s} {'share':>6s} {'target':>8s} {'error':>8s} {'bias':>7s} {'of sq. error':>12s}")
    for name, figures in regimes.items():
        if not figures["share"]:
            print(f"{name:18s} {0:6.3f}")
            continue
        print(
            f"{name:18s} {figures['share']:6.3f} {figures['target_rms_mm'][last]:8.2f} "
            f"{figures['error_rms_mm'][last]:8.2f} {figures['bias_mm']:+7.2f} {figures['error_share']:12.3f}"
        )
    print(
        f"(RMS of |a_{last[0].replace('v', 'u')}| and of its error, and the error's mean upwards, mm per frame)"
    )
    if simulator.config.uses_velocities:
        print(
            f"\n{'per object':18s} {'share':>6s} {'dv':>7s} {'error':>7s} {'caught':>7s}"
            f" {'dw':>7s} {'error':>7s} {'caught':>7s}"
        )
        for name, figures in regimes.items():
            if figures["share"]:
                response = figures["response"]
                cells = [
                    f"{response[part][key]:7.3f}" if response[part][key] is not None else f"{'-':>7s}"
                    for part in ("linear", "angular")
                    for key in ("target_rms", "error_rms", "captured")
                ]
                print(f"{name:18s} {response['share']:6.3f} " + " ".join(cells))
        print(
            "(RMS of the recorded change over the step of each object's velocity beyond free fall's, m/s,"
            " and of its spin, rad/s; of the network's error; and the share of the change it follows)"
        )
    for radius in args.radii:
        key = f"{radius:g}"
        cells = [
            f"{name} {figures['out_of_reach'][key]['share']:.3f} ({figures['out_of_reach'][key]['error_share']:.3f})"
            for name, figures in regimes.items()
            if figures["share"]
        ]
        print(
            f"no face-face edge at {key} m, share of the regime (of all squared error): " + ", ".join(cells)
        )
    if args.output:
        write_json(
            args.output,
            {
                "model": args.model,
                "data": args.data,
                "trajectories": args.trajectories,
                "radii": args.radii,
                "regimes": regimes,
            },
        )
        print(args.output)


if __name__ == "__main__":
    main()
