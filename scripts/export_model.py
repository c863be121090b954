"""`python scripts/export_model.py SOURCE DESTINATION [--trained-on DATA] [--dt S --gravity X Y Z] [--rotations K]`:
ship a model without its training state (`--trained-on`: the training file of a run saved
before models stored the properties, time step and gravity they were trained at; `--dt` and
`--gravity`: those two of such a run, when its file is not at hand; `--rotations K`: the
turns about gravity `rollout` and `evaluate` average its network over unless told otherwise).
`make checkpoints` runs it for the bundled models."""

import argparse

from fignetctl.core.model.checkpoint import export_checkpoint

if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python scripts/export_model.py", description=__doc__)
    parser.add_argument("source")
    parser.add_argument("destination")
    parser.add_argument("--trained-on", default=None)
    parser.add_argument("--dt", type=float, default=None, help="seconds per frame of the training data")
    parser.add_argument("--gravity", type=float, nargs=3, default=None, help="m/s² of the training data")
    parser.add_argument(
        "--rotations",
        type=int,
        default=None,
        help="turns about gravity its network is averaged over by default",
    )
    args = parser.parse_args()
    print(
        export_checkpoint(
            args.source, args.destination, args.trained_on, args.dt, args.gravity, args.rotations
        )
    )
