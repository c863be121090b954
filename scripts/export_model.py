"""`python scripts/export_model.py SOURCE DESTINATION [--trained-on DATA]`: ship a model
without its training state (`--trained-on`: the training file of a run saved before models
stored the properties they were trained on). `make checkpoints` runs it for the bundled models."""

import argparse

from fignetctl.core.model.checkpoint import export_checkpoint

if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python scripts/export_model.py", description=__doc__)
    parser.add_argument("source")
    parser.add_argument("destination")
    parser.add_argument("--trained-on", default=None)
    args = parser.parse_args()
    print(export_checkpoint(args.source, args.destination, args.trained_on))
