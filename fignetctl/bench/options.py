"""Command-line options the scripts in benchmarks/ share."""

from __future__ import annotations

import argparse


def add_rotations_option(parser: argparse.ArgumentParser) -> None:
    """`--rotations K`: average the network over K turns about gravity (pass it to `load_model`);
    left out, the model file's own. A K outside 1–MAX_ROTATIONS is a usage error."""
    parser.add_argument(
        "--rotations",
        type=_turns,
        default=None,
        metavar="K",
        help="average the network over this many turns about gravity (default: the model file's)",
    )


def _turns(text: str) -> int:
    from fignetctl.core.model.simulator import MAX_ROTATIONS

    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= MAX_ROTATIONS:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of turns from 1 to {MAX_ROTATIONS}")
    return value
