"""The containers of the project's files: .npz (cameras.npz, volume.npz) and torch files (model.pt,
nerf.pt), the container and its `format` / `format_version` checked once for every reader."""

from __future__ import annotations

import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np

from fignetctl.errors import FormatError

NPZ_ERRORS = (
    OSError,
    ValueError,
    EOFError,
    KeyError,
    RuntimeError,
    SyntaxError,
    zipfile.BadZipFile,
    zlib.error,
    tokenize.TokenError,
)
"""What numpy raises on a damaged .npz: a broken zip, a truncated member, an unparsable .npy
header (numpy tokenizes and evaluates the header's text)."""


def require_regular_file(path, kind: str = "") -> Path:
    """`path` as a Path, or a one-line FormatError when it is missing or is not a regular file
    (a directory, a FIFO or a device, which a reader could wait on for ever). `kind`: what the
    file is ('model'), for the message."""
    path = Path(path)
    if not path.exists():
        raise FormatError(f"{path}: no such {kind + ' ' if kind else ''}file")
    if not path.is_file():
        raise FormatError(f"{path}: not a regular file (a directory, pipe or device); give a file")
    return path


def read_npz_arrays(path, name: str) -> dict:
    """Every array of an .npz (no pickles), or a one-line FormatError naming `path` and what
    the file should have been (`name`)."""
    path = require_regular_file(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except NPZ_ERRORS as error:
        message = " ".join(str(error).split())[:160]
        raise FormatError(f"{path}: not a readable {name} ({type(error).__name__}: {message})") from None


def read_npz_document(path, name: str, fmt: str, version: int, required=()) -> dict:
    """The arrays of an .npz whose `format` is `fmt` and `format_version` is `version`, with
    every field of `required` present; any problem is a one-line FormatError naming `path`.

    name : what the file is, for the messages (e.g. 'cameras.npz')
    """
    arrays = read_npz_arrays(path, name)
    found = str(arrays.get("format", ""))
    if found != fmt:
        raise FormatError(f"{path}: 'format' is {found!r}, expected {fmt!r}")
    stored = arrays.get("format_version")
    if stored is None or stored.shape != () or stored.dtype.kind not in "iu" or int(stored) != version:
        raise FormatError(
            f"{path}: format_version {None if stored is None else stored.tolist()!r} is not supported "
            f"(this fignetctl reads {version})"
        )
    for field in required:
        if field not in arrays:
            raise FormatError(f"{path}: missing field {field!r}")
    return arrays


def read_torch_document(path, kind: str, readable_as: str, fmt: str, version: int) -> dict:
    """The dictionary of a torch file (loaded with weights_only) whose `format` is `fmt` and
    `format_version` is `version` (or one of a tuple of versions); any problem is a one-line
    FormatError naming `path`.

    kind : 'model', 'nerf', ... for the messages; readable_as : what the file should read as
    """
    import torch

    path = require_regular_file(path, kind)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types for corrupt or foreign files
        raise FormatError(f"{path}: not a readable {readable_as} ({type(error).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != fmt:
        raise FormatError(f"{path}: not a fignetctl {kind} file (no format={fmt!r})")
    versions = tuple(version) if isinstance(version, (tuple, list)) else (version,)
    if payload.get("format_version") not in versions:
        readable = " or ".join(str(v) for v in versions)
        raise FormatError(
            f"{path}: {kind} format_version {payload.get('format_version')!r} is not supported "
            f"(this fignetctl reads {readable}); upgrade fignetctl"
        )
    stored = payload.get(WEIGHTS_HASH_KEY)
    if stored is not None and (
        not isinstance(payload.get("model"), dict) or weights_sha256(payload["model"]) != stored
    ):
        raise FormatError(f"{path}: the weights do not match their stored checksum; the file is damaged")
    return payload


WEIGHTS_HASH_KEY = "weights_sha256"


def weights_sha256(state: dict) -> str:
    """sha256 of a state dict's names, dtypes, shapes and bytes, in name order: written with the
    weights, checked when they are read, so a flipped byte in them is an error, not a model."""
    import hashlib

    import torch

    digest = hashlib.sha256()
    for name in sorted(state):
        tensor = state[name]
        if not isinstance(tensor, torch.Tensor):
            return ""
        tensor = tensor.detach().cpu().contiguous()
        digest.update(f"{name}:{tensor.dtype}:{tuple(tensor.shape)};".encode())
        digest.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes() if tensor.numel() else b"")
    return digest.hexdigest()


def write_npz_document(path, fmt: str, version: int, arrays: dict, provenance=None) -> Path:
    """Write an .npz atomically: `format`, `format_version` (what `read_npz_document` checks),
    `arrays` and the provenance stamp (provenance.stamp; default: the version alone). Returns
    the path."""
    from fignetctl.core.atomic import atomic_path
    from fignetctl.core.provenance import as_strings, stamp

    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez(
            f,
            format=np.array(fmt),
            format_version=np.array(version),
            **arrays,
            **as_strings(provenance or stamp()),
        )
    return Path(path)


def write_torch_document(
    path, fmt: str, version: int, module, fields: dict, training_state=None, provenance=None
):
    """Write a torch file atomically: `format`, `format_version`, the provenance stamp (default:
    the version alone), `fields`, the `module`'s weights on the CPU and, when given, the
    `training_state` that makes it resumable. Returns the path."""
    from fignetctl.core.provenance import as_strings, stamp

    payload = {
        "format": fmt,
        "format_version": version,
        **as_strings(provenance or stamp()),
        **fields,
        "model": {k: v.detach().cpu() for k, v in module.state_dict().items()},
    }
    if training_state is not None:
        payload["training_state"] = training_state
    return save_torch_payload(path, payload)


def save_torch_payload(path, payload: dict) -> Path:
    """Write a torch document's dictionary atomically, its `model` weights hashed under
    WEIGHTS_HASH_KEY (what `read_torch_document` checks). Returns the path."""
    import torch

    from fignetctl.core.atomic import atomic_path

    payload[WEIGHTS_HASH_KEY] = weights_sha256(payload["model"])
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


LOADING_ERRORS = (KeyError, TypeError, ValueError, RuntimeError, AttributeError, IndexError, RecursionError)
"""What building a module from a file's settings and loading its weights raises when they disagree."""


def weights_do_not_fit(path, error: Exception) -> FormatError:
    """The one-line error for a file whose weights do not fit its stored settings."""
    return FormatError(f"{path}: the weights do not fit the stored settings ({str(error).splitlines()[0]})")
