"""`python -m fignetctl.core.model.export SOURCE DESTINATION`: ship a model without training state."""

import sys

from fignetctl.core.model.checkpoint import export_checkpoint

if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python -m fignetctl.core.model.export SOURCE.pt DESTINATION.pt")
    print(export_checkpoint(sys.argv[1], sys.argv[2]))
