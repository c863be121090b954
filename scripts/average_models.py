"""`python scripts/average_models.py MODEL MODEL [MODEL ...] -o DESTINATION`: one model file
whose weights are the mean of those of runs continued from one model with other seeds (a model
soup). Measure it beside each run: docs/training-record.md has what it did for the velocity state."""

import argparse
import sys

from fignetctl.core.model.checkpoint import average_checkpoints
from fignetctl.errors import FignetError

if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python scripts/average_models.py", description=__doc__)
    parser.add_argument("sources", nargs="+")
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args()
    try:
        print(average_checkpoints(args.sources, args.output))
    except FignetError as error:
        sys.exit(f"error: {error}")
