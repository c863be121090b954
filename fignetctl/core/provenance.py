"""Where an output came from: the fignetctl version that wrote it and the hashes of its inputs.

Every output format carries the same two keys (docs/formats.md):

    fignetctl_version   the package version, a string
    inputs_sha256       {role: SHA-256 hex} of the files (or folders) it was made from, e.g.
                        {"scene": ..., "model": ...} for a rollout; {} when made from settings alone

stored as an array entry (cameras.npz, volume.npz), a file attribute (trajectory .h5), a
payload entry (nerf.pt, model files) or a top-level key (json reports). `read_provenance`
reads them back from any of these.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

VERSION_KEY = "fignetctl_version"
INPUTS_KEY = "inputs_sha256"


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes, as 64 hex digits (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def path_sha256(path) -> str:
    """file_sha256 of a file; of a folder, the SHA-256 over its regular files' relative paths
    and hashes, in sorted order (hidden files skipped)."""
    path = Path(path)
    if not path.is_dir():
        return file_sha256(path)
    digest = hashlib.sha256()
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        relative = file.relative_to(path)
        if any(part.startswith(".") for part in relative.parts):
            continue
        digest.update(f"{relative.as_posix()}\0{file_sha256(file)}\n".encode())
    return digest.hexdigest()


def stamp(**inputs) -> dict:
    """{fignetctl_version, inputs_sha256} of an output made from these files or folders
    (role=path; None values are left out)."""
    from fignetctl import __version__

    return {
        VERSION_KEY: __version__,
        INPUTS_KEY: {role: path_sha256(path) for role, path in inputs.items() if path is not None},
    }


def as_strings(provenance: dict) -> dict:
    """The stamp with inputs_sha256 as a json string: for .npz arrays and HDF5 attributes."""
    return {
        VERSION_KEY: provenance[VERSION_KEY],
        INPUTS_KEY: json.dumps(provenance[INPUTS_KEY], sort_keys=True),
    }


def read_provenance(path) -> dict:
    """{fignetctl_version, inputs_sha256} of an output file of any format (.npz, .h5, .pt,
    .json); a missing key reads as None."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        import numpy as np

        with np.load(path, allow_pickle=False) as data:
            found = {key: str(data[key]) for key in (VERSION_KEY, INPUTS_KEY) if key in data.files}
    elif suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "r") as f:
            found = {key: f.attrs[key] for key in (VERSION_KEY, INPUTS_KEY) if key in f.attrs}
    elif suffix == ".pt":
        import torch

        payload = torch.load(path, map_location="cpu", weights_only=True)
        found = {key: payload[key] for key in (VERSION_KEY, INPUTS_KEY) if key in payload}
    else:
        document = json.loads(path.read_text())
        found = {key: document[key] for key in (VERSION_KEY, INPUTS_KEY) if key in document}
    return from_strings(found)


def from_strings(stored) -> dict:
    """The stamp from what `as_strings` stored (a dict, HDF5 attributes, ...); a missing key
    reads as None."""
    inputs = stored.get(INPUTS_KEY)
    if isinstance(inputs, (str, bytes)):
        inputs = json.loads(inputs)
    version = stored.get(VERSION_KEY)
    return {VERSION_KEY: None if version is None else str(version), INPUTS_KEY: inputs}
