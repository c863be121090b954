"""`python scripts/take_trajectories.py SOURCE DESTINATION -n N [--start K]`: trajectories K to
K + N − 1 (in file order) of a trajectory file, as a smaller file of their own, for a machine
that takes only so much data along (a lent GPU machine takes 64 MiB with the code). The frame
arrays are stored byte-shuffled at gzip level 9 with their checksums, the few numbers per object
plainly: about 53 KB per movi-b trajectory against 64 KB in make-dataset's files, so 1000 fit
beside the code (docs/training-record.md, "The continuations", stage 13). The copy is read back with
fignetctl's reader before it replaces DESTINATION."""

import argparse
import sys

import h5py

from fignetctl.core.atomic import atomic_path
from fignetctl.core.containers import require_regular_file
from fignetctl.core.trajectory import read_trajectories
from fignetctl.errors import FignetError, FormatError


def take(source, destination, count: int, start: int = 0):
    source = require_regular_file(source, "trajectory")
    try:
        f = h5py.File(source, "r")
        keys = list(f["trajectories"].keys())
    except (OSError, KeyError) as error:
        raise FormatError(f"{source}: not a trajectory file ({error}); give one from make-dataset") from None
    with f:
        if len(keys) < start + count:
            raise FignetError(
                f"{source}: holds {len(keys)} trajectories, not {start + count}; "
                "ask for fewer (-n) or start earlier (--start)"
            )
        with atomic_path(destination) as tmp:
            with h5py.File(tmp, "w") as g:
                copy(f, g, keys[start : start + count], f"{source}: {start}..{start + count - 1}")
            read_trajectories(tmp)  # a clear error, and no DESTINATION, if the copy is not a valid file
    return destination


def copy(f, g, keys, taken_from) -> None:
    for name, value in f.attrs.items():
        g.attrs[name] = value
    g.attrs["num_trajectories"] = len(keys)
    g.attrs["taken_from"] = taken_from
    f.copy("meshes", g)
    trajectories = g.create_group("trajectories")
    for key in keys:
        source, target = f["trajectories"][key], trajectories.create_group(key)
        for name, dataset in source.items():
            if dataset.ndim >= 2 and dataset.shape[0] > 1:  # (frames, objects, 3 or 4)
                target.create_dataset(
                    name,
                    data=dataset[()],
                    compression="gzip",
                    compression_opts=9,
                    shuffle=True,
                    fletcher32=True,
                )
            else:
                target.create_dataset(name, data=dataset[()], dtype=dataset.dtype)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(prog="python scripts/take_trajectories.py", description=__doc__)
    parser.add_argument("source")
    parser.add_argument("destination")
    parser.add_argument("-n", type=int, required=True, help="how many trajectories")
    parser.add_argument("--start", type=int, default=0, help="the first one's position in the file")
    args = parser.parse_args()
    if args.n < 1 or args.start < 0:
        sys.exit("error: -n must be 1 or more and --start 0 or more")
    try:
        print(take(args.source, args.destination, args.n, args.start))
    except (FignetError, OSError) as error:  # OSError: a damaged source chunk, a full disk
        sys.exit(f"error: {error}")
