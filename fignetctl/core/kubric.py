"""Kubric scenes (`metadata.json` of a MOVi-style worker) as trajectory files.

What is read, per Kubric's published schema (`kubric/utils.py`: get_scene_metadata,
get_instance_info):

    metadata.frame_rate, metadata.num_frames, metadata.gravity (optional, default (0, 0, −9.81))
    instances[i].asset_id, positions (T, 3), quaternions (T, 4) w x y z, velocities (T, 3),
        angular_velocities (T, 3), mass, friction, restitution,
        scale or size (uniform; MOVi-B writes "size", MOVi-C "scale"; default 1),
        is_dynamic (optional, default true: MOVi's static objects say false)

Kubric keeps the floor out of `instances`; it is added as a static square at z = 0 with the
given friction and restitution (MOVi-B/C: 0.3 and 0.5). Each asset's collision mesh is found in
the assets folder as `<asset_id>/collision_geometry.obj` (Kubric's asset layout),
`<asset_id>.obj` or `<asset_id>/<asset_id>.obj`, and used as it is: in the object frame that
Kubric's positions and quaternions move.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fignetctl.core.containers import require_regular_file
from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile
from fignetctl.errors import FormatError

FLOOR = "kubric_floor"
MESH_PATTERNS = ("{id}/collision_geometry.obj", "{id}.obj", "{id}/{id}.obj")


def read_metadata(path) -> dict:
    """A Kubric metadata.json as a dict; FormatError when it is not one."""
    path = require_regular_file(path)
    try:
        document = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise FormatError(f"{path}: not a Kubric metadata.json ({type(error).__name__})") from None
    if not isinstance(document, dict) or not isinstance(document.get("instances"), list):
        raise FormatError(f"{path}: not a Kubric metadata.json (no 'instances' list)")
    if not isinstance(document.get("metadata"), dict) or "frame_rate" not in document["metadata"]:
        raise FormatError(f"{path}: not a Kubric metadata.json (no 'metadata.frame_rate')")
    if not document["instances"]:
        raise FormatError(f"{path}: the scene has no instances")
    return document


def find_mesh(assets, asset_id: str) -> Path:
    """The collision mesh file of `asset_id` in the assets folder."""
    candidates = [Path(assets) / pattern.format(id=asset_id) for pattern in MESH_PATTERNS]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise FormatError(
        f"no mesh for Kubric asset {asset_id!r}: looked for {', '.join(str(c) for c in candidates)}"
    )


def _array(info: dict, field: str, shape: tuple, where: str) -> np.ndarray:
    try:
        value = np.asarray(info[field], np.float64)
    except KeyError:
        raise FormatError(f"{where}: missing field {field!r}") from None
    except (TypeError, ValueError):
        raise FormatError(f"{where}: field {field!r} is not numeric") from None
    if value.ndim != len(shape) or any(
        want is not None and have != want for have, want in zip(value.shape, shape)
    ):
        raise FormatError(f"{where}: field {field!r} has shape {value.shape}, expected {shape}")
    if not np.all(np.isfinite(value)):
        raise FormatError(f"{where}: field {field!r} holds NaN or inf")
    return value


def _scale(info: dict, where: str) -> float:
    scale = np.asarray(info.get("scale", info.get("size", 1.0)), np.float64).reshape(-1)
    if scale.size not in (1, 3) or not np.all(np.isfinite(scale)) or np.any(scale <= 0):
        raise FormatError(f"{where}: 'scale' must be one positive number or three")
    if np.ptp(scale) > 1e-6 * scale.max():
        raise FormatError(
            f"{where}: scale {scale.tolist()} is not uniform; trajectory files hold uniform scales"
        )
    return float(scale[0])


def _instance(info, frames: int, where: str) -> dict:
    """One instance's fields, checked: asset, scale, motion (T, 3|4) and properties."""
    if not isinstance(info, dict) or not isinstance(info.get("asset_id"), str):
        raise FormatError(f"{where}: no 'asset_id'")
    motion = {
        field: _array(info, field, (frames, width), where)
        for field, width in (
            ("positions", 3),
            ("quaternions", 4),
            ("velocities", 3),
            ("angular_velocities", 3),
        )
    }
    norms = np.linalg.norm(motion["quaternions"], axis=1, keepdims=True)
    if np.any(norms < 1e-6):
        raise FormatError(f"{where}: a quaternion is zero")
    motion["quaternions"] = motion["quaternions"] / norms
    mass, friction, restitution = (
        float(_array(info, key, (), where)) for key in ("mass", "friction", "restitution")
    )
    if min(mass, friction, restitution) < 0:
        raise FormatError(f"{where}: mass, friction and restitution must not be negative")
    dynamic = bool(info.get("is_dynamic", True))
    return {
        "asset": info["asset_id"],
        "scale": _scale(info, where),
        "static": not dynamic,
        "properties": (mass if dynamic else 0.0, friction, restitution),
        **motion,
    }


def scene_trajectory(document: dict, floor_friction: float, floor_restitution: float, where: str):
    """(Trajectory, dt, gravity) of one metadata document, the floor first."""
    frames = len(document["instances"][0].get("positions", []))
    if frames < 2:
        raise FormatError(f"{where}: instances have {frames} frames; a trajectory needs 2 or more")
    objects = [
        _instance(info, frames, f"{where}: instance {i}") for i, info in enumerate(document["instances"])
    ]
    floor_motion = {"positions": np.zeros((frames, 3)), "quaternions": np.tile([1.0, 0, 0, 0], (frames, 1))}

    def column(field):  # (T, 1 + instances, width): the floor, then the instances
        fill = floor_motion.get(field, np.zeros((frames, 3)))
        return np.stack([fill, *(o[field] for o in objects)], axis=1).astype(np.float32)

    properties = np.array(
        [(0.0, floor_friction, floor_restitution), *(o["properties"] for o in objects)], np.float32
    )
    trajectory = Trajectory(
        mesh_names=np.array([FLOOR, *(o["asset"] for o in objects)], dtype=object),
        scales=np.array([1.0, *(o["scale"] for o in objects)], np.float32),
        positions=column("positions"),
        quaternions=column("quaternions"),
        static=np.array([True, *(o["static"] for o in objects)]),
        mass=properties[:, 0],
        friction=properties[:, 1],
        restitution=properties[:, 2],
        velocities=column("velocities"),
        angular_velocities=column("angular_velocities"),
    )
    metadata = document["metadata"]
    frame_rate = float(_array(metadata, "frame_rate", (), where))
    if frame_rate <= 0:
        raise FormatError(f"{where}: metadata.frame_rate must be positive")
    gravity = (
        _array(metadata, "gravity", (3,), where) if "gravity" in metadata else np.array([0.0, 0.0, -9.81])
    )
    return trajectory, 1.0 / frame_rate, gravity


def floor_square(half_size: float) -> Mesh:
    """A square of side 2 · half_size at z = 0, facing up."""
    corners = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32) * [
        half_size,
        half_size,
        1,
    ]
    return Mesh(corners.astype(np.float32), np.array([[0, 1, 2], [0, 2, 3]], np.int32))


def kubric_file(
    paths, assets, floor_friction=0.3, floor_restitution=0.5, floor_half_size=10.0
) -> TrajectoryFile:
    """One trajectory per metadata.json (ids 00000, 00001, ...), all at the first file's frame
    rate and gravity (a file that differs is refused)."""
    from fignetctl.core.obj import load_obj

    meshes = {FLOOR: floor_square(floor_half_size)}
    trajectories, dt, gravity = {}, None, None
    for number, path in enumerate(paths):
        document = read_metadata(path)
        for info in document["instances"]:
            asset = info.get("asset_id") if isinstance(info, dict) else None
            if isinstance(asset, str) and asset not in meshes:
                mesh = load_obj(find_mesh(assets, asset))
                meshes[asset] = Mesh(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.int32))
        trajectory, step, down = scene_trajectory(document, floor_friction, floor_restitution, str(path))
        if dt is None:
            dt, gravity = step, down
        elif abs(step - dt) > 1e-9 * dt or not np.allclose(down, gravity):
            raise FormatError(
                f"{path}: frame rate or gravity differs from {paths[0]}'s; import them separately"
            )
        trajectories[f"{number:05d}"] = trajectory
    return TrajectoryFile(
        dt, np.asarray(gravity), meshes, trajectories, {"source": "fignetctl import-kubric"}
    )
