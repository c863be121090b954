"""`python scripts/average_models.py MODEL MODEL [MODEL ...] -o DESTINATION [--properties-from K]`:
one model file whose weights are the mean of those of runs continued from one model with other
seeds (a model soup). The files must record the same settings and trained properties;
`--properties-from K` lets the properties differ (runs on one dataset whose properties two
versions of the trainer measured differently) and takes the K-th file's (1 is the first).
Measure the mean beside each run: docs/training-record.md has what it did for the velocity state."""

import argparse
import sys

from fignetctl.core.model.checkpoint import PropertiesDiffer, average_checkpoints
from fignetctl.errors import FignetError

if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python scripts/average_models.py", description=__doc__)
    parser.add_argument("sources", nargs="+")
    parser.add_argument("-o", "--output", required=True)
    parser.add_argument(
        "--properties-from",
        type=int,
        metavar="K",
        help="the K-th model's trained properties (1 is the first), where theirs differ",
    )
    args = parser.parse_args()
    if args.properties_from is not None and not 1 <= args.properties_from <= len(args.sources):
        parser.error(f"--properties-from: give 1 to {len(args.sources)}, the position of one of the models")
    chosen = None if args.properties_from is None else args.properties_from - 1
    try:
        print(average_checkpoints(args.sources, args.output, chosen))
    except PropertiesDiffer as error:
        sys.exit(f"error: {error}: --properties-from K")
    except FignetError as error:
        sys.exit(f"error: {error}")
