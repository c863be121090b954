"""`volume.npz`, format `fignetctl.volume`, format_version 1: where an extracted object lives.

Written by `extract-mesh`, read by `build-graph` and `rerender`. World units (metres, z up):

    format, format_version
    lower (3,), upper (3,)                  the object's box V_o (the region whose density is the object)
    origin (3,)                             the object frame's origin in world: object.obj's vertices are
                                            stored relative to it, rest orientation identity, so the
                                            object's position at rest in a trajectory is `origin`
    passive_lower (3,), passive_upper (3,)  the box the environment mesh was extracted from
    object_mesh, environment_mesh           file names of the meshes (relative to volume.npz's folder)
    environment_origin (3,)                 optional: the environment mesh's frame origin (default 0:
                                            environment.obj is in world coordinates)
    settings (json str)                     optional: how the meshes were made

Writes are atomic; `read_volume` raises FormatError naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from fignetctl.core.containers import read_npz_document, write_npz_document
from fignetctl.errors import FormatError

FORMAT = "fignetctl.volume"
FORMAT_VERSION = 1
_VECTORS = ("lower", "upper", "origin", "passive_lower", "passive_upper")


@dataclasses.dataclass
class Volume:
    """The object's box, its frame origin, the environment's box and the mesh file names."""

    lower: np.ndarray  # (3,) float64
    upper: np.ndarray  # (3,) float64
    origin: np.ndarray  # (3,) float64
    passive_lower: np.ndarray  # (3,) float64
    passive_upper: np.ndarray  # (3,) float64
    object_mesh: str = "object.obj"
    environment_mesh: str = "environment.obj"
    environment_origin: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    settings: dict = dataclasses.field(default_factory=dict)

    @property
    def size(self) -> np.ndarray:
        """(3,) edge lengths of V_o."""
        return self.upper - self.lower

    def contains(self, points) -> np.ndarray:
        """points (P, 3) -> (P,) bool: inside the closed box V_o."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        return np.all((points >= self.lower) & (points <= self.upper), axis=1)


def validate_volume(volume: Volume, where: str = "volume") -> Volume:
    """Check shapes, finiteness and box order; return the volume with float64 vectors."""
    values = {}
    for field in (*_VECTORS, "environment_origin"):
        value = np.asarray(getattr(volume, field))
        if value.dtype.kind not in "biuf":
            raise FormatError(f"{where}: field {field!r} must hold real numbers, got {value.dtype}")
        value = value.astype(np.float64)
        if value.shape != (3,):
            raise FormatError(f"{where}: field {field!r} must have shape (3,), got {value.shape}")
        if not np.all(np.isfinite(value)):
            raise FormatError(f"{where}: field {field!r} holds NaN or inf")
        values[field] = value
    for low, high in (("lower", "upper"), ("passive_lower", "passive_upper")):
        if np.any(values[high] <= values[low]):
            raise FormatError(f"{where}: {high!r} must be greater than {low!r} on every axis")
    for field in ("object_mesh", "environment_mesh"):
        name = str(getattr(volume, field))
        if not name:
            raise FormatError(f"{where}: field {field!r} is empty")
        if name != Path(name).name or name in (".", ".."):  # a file beside volume.npz, never elsewhere
            raise FormatError(f"{where}: field {field!r} is {name!r}, not a file name beside volume.npz")
    if not isinstance(volume.settings, dict):
        raise FormatError(f"{where}: field 'settings' must be a json object")
    return dataclasses.replace(
        volume, **values, object_mesh=str(volume.object_mesh), environment_mesh=str(volume.environment_mesh)
    )


def write_volume(path, volume: Volume, provenance: dict | None = None) -> Path:
    """Validate, then write volume.npz atomically, stamped with `provenance` (provenance.stamp;
    default: the version alone)."""
    volume = validate_volume(volume, str(path))
    arrays = {field: getattr(volume, field) for field in (*_VECTORS, "environment_origin")}
    arrays["object_mesh"] = np.array(volume.object_mesh)
    arrays["environment_mesh"] = np.array(volume.environment_mesh)
    arrays["settings"] = np.array(json.dumps(volume.settings, sort_keys=True))
    return write_npz_document(path, FORMAT, FORMAT_VERSION, arrays, provenance)


def read_volume(path) -> Volume:
    """Read and check volume.npz; any problem is a one-line FormatError."""
    path = Path(path)
    arrays = read_npz_document(
        path, "volume.npz", FORMAT, FORMAT_VERSION, (*_VECTORS, "object_mesh", "environment_mesh")
    )
    for field in ("object_mesh", "environment_mesh", *(("settings",) if "settings" in arrays else ())):
        if arrays[field].shape != () or arrays[field].dtype.kind != "U":
            raise FormatError(
                f"{path}: field {field!r} must be one string, got {arrays[field].shape} {arrays[field].dtype}"
            )
    try:
        settings = json.loads(str(arrays["settings"])) if "settings" in arrays else {}
    except (ValueError, RecursionError):
        raise FormatError(f"{path}: field 'settings' is not json") from None
    volume = Volume(
        **{field: arrays[field] for field in _VECTORS},
        object_mesh=str(arrays["object_mesh"]),
        environment_mesh=str(arrays["environment_mesh"]),
        environment_origin=arrays.get("environment_origin", np.zeros(3)),
        settings=settings,
    )
    return validate_volume(volume, str(path))
