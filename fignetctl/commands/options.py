"""Options shared by the commands, defined once."""

from pathlib import Path

import click

overwrite_option = click.option(
    "--overwrite", is_flag=True, help="Replace outputs that already exist."
)
seed_option = click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
device_option = click.option(
    "--device",
    type=click.Choice(["cpu", "cuda", "auto"]),
    default="auto",
    show_default=True,
    help="Torch device; 'auto' uses CUDA when available.",
)
def sleep_option(default):
    return click.option(
        "--sleep/--no-sleep", default=default, show_default=True,
        help="Stop simulating objects that have come to rest, until something comes near them (docs/simulator.md).",
    )


def free_flight_option(default):
    return click.option(
        "--free-flight/--no-free-flight", default=default, show_default=True,
        help="Move objects that touch nothing in exact free flight (gravity, constant spin) instead of by the "
             "network, which is not run while nothing touches (docs/simulator.md).",
    )


def keep_out_option(default):
    return click.option(
        "--keep-out/--no-keep-out", default=default, show_default=True,
        help="After each step, move an object that passed into static geometry (the floor, the environment, "
             "objects asleep) back out along the face's normal: a geometric guard, not the network (docs/simulator.md).",
    )


rerun_option = click.option(
    "--rerun",
    "rerun_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also log what this command did to a rerun recording (.rrd).",
)


def output_path(path, overwrite, param_name="--output"):
    """Return `path` as a Path; refuse an existing file unless --overwrite was given."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise click.BadParameter(f"{path} exists; pass --overwrite to replace it", param_hint=param_name)
    return path


def resolve_device(device):
    """'auto' -> 'cuda' when torch sees a GPU, else 'cpu'; 'cuda' without a GPU is an error."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise click.BadParameter("CUDA was asked for but torch sees no GPU", param_hint="--device")
    return device


def progress(iterable=None, **kwargs):
    """A tqdm progress bar on stderr, hidden when stderr is not a terminal unless forced."""
    import sys

    from tqdm import tqdm

    kwargs.setdefault("file", sys.stderr)
    kwargs.setdefault("dynamic_ncols", True)
    kwargs.setdefault("disable", None)
    return tqdm(iterable, **kwargs)
