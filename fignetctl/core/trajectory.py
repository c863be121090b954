"""The trajectory file, format `fignetctl.trajectories`, version 2 (see docs/formats.md).

One HDF5 file holds meshes (object frame, origin at the centre of mass) and any number of
trajectories of objects that use them. The same format stores a dataset, a scene
(2 frames: t-1 and t) and a rollout. Units: metres, seconds, kilograms; z is up.

World vertex = R(q) · (scale · v) + p, with q = (w, x, y, z) object-to-world.

Version 2 adds the optional per-frame `velocities` and `angular_velocities` (T, O, 3), the
instantaneous linear (m/s) and angular (rad/s) velocity of each object in the world frame.
Version 1 files are read as before; they have no velocities (`Trajectory.velocities` is None)
and whoever needs them estimates them from the frames (`estimated_velocities`).

`write_trajectories` is atomic; `read_trajectories` validates every required field and
raises `FormatError` with a message naming the file, the trajectory and the field.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from fignetctl.core.atomic import atomic_path
from fignetctl.core.containers import require_regular_file
from fignetctl.core.hdf5_guard import read_guarded
from fignetctl.core.provenance import as_strings, stamp
from fignetctl.errors import FormatError

FORMAT = "fignetctl.trajectories"
FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (1, 2)
QUATERNION_TOLERANCE = 1e-3


@dataclasses.dataclass
class Mesh:
    """A triangle mesh in its object frame.

    vertices : (V, 3) float32, origin at the centre of mass, unscaled
    faces : (F, 3) int32, counter-clockwise seen from outside
    """

    vertices: np.ndarray
    faces: np.ndarray


@dataclasses.dataclass
class Trajectory:
    """O objects over T frames.

    mesh_names : (O,) str
    scales : (O,) float32
    positions : (T, O, 3) float32
    quaternions : (T, O, 4) float32, w x y z
    static : (O,) bool, True for objects moved from outside (floor, environment)
    mass, friction, restitution : (O,) float32
    velocities, angular_velocities : (T, O, 3) float32 world-frame m/s and rad/s at each frame,
        both or neither (None: not recorded)
    extras : optional further (name -> array) datasets, kept on a round trip
    """

    mesh_names: np.ndarray
    scales: np.ndarray
    positions: np.ndarray
    quaternions: np.ndarray
    static: np.ndarray
    mass: np.ndarray
    friction: np.ndarray
    restitution: np.ndarray
    velocities: np.ndarray | None = None
    angular_velocities: np.ndarray | None = None
    extras: dict = dataclasses.field(default_factory=dict)

    @property
    def has_velocities(self) -> bool:
        return self.velocities is not None

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def num_objects(self) -> int:
        return int(self.positions.shape[1])

    @property
    def properties(self) -> np.ndarray:
        """(O, 3) mass, friction, restitution per object."""
        return np.stack([self.mass, self.friction, self.restitution], axis=1)

    def frames(self, start: int, stop: int) -> Trajectory:
        """The same objects restricted to frames [start, stop)."""
        return dataclasses.replace(
            self,
            positions=self.positions[start:stop],
            quaternions=self.quaternions[start:stop],
            velocities=None if self.velocities is None else self.velocities[start:stop],
            angular_velocities=None
            if self.angular_velocities is None
            else self.angular_velocities[start:stop],
            extras={},
        )


@dataclasses.dataclass
class TrajectoryFile:
    """Everything in one trajectory file.

    dt : seconds between frames
    gravity : (3,) m/s²
    meshes : mesh name -> Mesh
    trajectories : trajectory id -> Trajectory (ids are kept in insertion order)
    attrs : optional further root attributes (source, seed, config, ...)
    """

    dt: float
    gravity: np.ndarray
    meshes: dict
    trajectories: dict
    attrs: dict = dataclasses.field(default_factory=dict)


def estimated_velocities(positions, quaternions, dt):
    """Velocities of frames that were not recorded with them (a version 1 file): backward
    differences, (x_t − x_{t−1}) / dt and the rotation q_t ⊗ q_{t−1}⁻¹ as a rotation vector / dt;
    frame 0 takes frame 1's (zero for a single frame).

    positions (T, O, 3), quaternions (T, O, 4) -> velocities, angular_velocities (T, O, 3) float64
    """
    from fignetctl.core.transforms import quat_conjugate, quat_multiply, quat_to_rotation_vector

    positions = np.asarray(positions, np.float64)
    quaternions = np.asarray(quaternions, np.float64)
    velocities = np.zeros_like(positions)
    angular = np.zeros_like(positions)
    if len(positions) > 1:
        velocities[1:] = np.diff(positions, axis=0) / dt
        turns = quat_multiply(quaternions[1:], quat_conjugate(quaternions[:-1]))
        angular[1:] = quat_to_rotation_vector(turns) / dt
        velocities[0], angular[0] = velocities[1], angular[1]
    return velocities, angular


# Required per-object fields: name -> (dtype kind check, trailing shape, per-frame?)
_OBJECT_FIELDS = {
    "scales": ("f", ()),
    "static": ("b", ()),
    "mass": ("f", ()),
    "friction": ("f", ()),
    "restitution": ("f", ()),
}
_FRAME_FIELDS = {"positions": 3, "quaternions": 4}
VELOCITY_FIELDS = ("velocities", "angular_velocities")  # optional, both or neither (version 2)


def write_trajectories(path, data: TrajectoryFile, compression: str | None = "gzip") -> Path:
    """Validate `data` and write it to `path` atomically (temporary file, then rename)."""
    import h5py

    path = Path(path)
    _validate(data, str(path))
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["dt"] = float(data.dt)
        f.attrs["gravity"] = np.asarray(data.gravity, np.float64)
        for key, value in {**as_strings(stamp()), **data.attrs}.items():
            f.attrs[key] = value
        meshes = f.create_group("meshes")
        for name, mesh in data.meshes.items():
            group = meshes.create_group(name)
            _checked_dataset(group, "vertices", np.asarray(mesh.vertices, np.float32))
            _checked_dataset(group, "faces", np.asarray(mesh.faces, np.int32))
        trajectories = f.create_group("trajectories")
        for key, trajectory in data.trajectories.items():
            _write_one(trajectories.create_group(str(key)), trajectory, compression)
    return path


def _write_one(group, trajectory: Trajectory, compression) -> None:
    import h5py

    names = [str(n) for n in trajectory.mesh_names]
    group.create_dataset("mesh_names", data=names, dtype=h5py.string_dtype("utf-8"))
    for field in (*_FRAME_FIELDS, *VELOCITY_FIELDS):
        value = getattr(trajectory, field)
        if value is not None:
            _checked_dataset(group, field, np.asarray(value, np.float32), compression)
    for field, (kind, _) in _OBJECT_FIELDS.items():
        dtype = bool if kind == "b" else np.float32
        _checked_dataset(group, field, np.asarray(getattr(trajectory, field), dtype))
    for field, value in trajectory.extras.items():
        group.create_dataset(field, data=value)


def _checked_dataset(group, name, value: np.ndarray, compression=None) -> None:
    """A dataset with HDF5's Fletcher-32 checksum: a damaged chunk fails to read (a one-line
    error) instead of reading as other numbers. Empty arrays cannot be chunked and go plain."""
    if value.size == 0:
        group.create_dataset(name, data=value)
    else:
        group.create_dataset(name, data=value, compression=compression, fletcher32=True)


def read_trajectories(path, trajectory_ids=None) -> TrajectoryFile:
    """Read and validate a trajectory file; optionally only the listed trajectory ids.

    Raises FormatError naming the file, the trajectory and the field for anything that
    does not follow the format (missing fields, wrong shapes or dtypes, non-unit
    quaternions, faces out of range, non-finite numbers, unknown format versions).
    """

    path = require_regular_file(path)
    _check_global_heaps(path)
    return read_guarded(_read_unguarded, path, trajectory_ids)


def _read_unguarded(path: Path, trajectory_ids) -> TrajectoryFile:
    import h5py

    try:
        with h5py.File(path, "r") as f:
            data = _read_open_file(f, str(path), trajectory_ids)
    except FormatError:
        raise
    except (
        OSError,
        KeyError,
        ValueError,
        TypeError,
        RuntimeError,
        IndexError,
        AttributeError,
        MemoryError,
    ) as error:
        # h5py reports damaged files with any of these, depending on where the damage is
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise FormatError(f"{path}: not a readable HDF5 trajectory file ({reason})") from None
    _validate(data, str(path))
    return data


def _check_global_heaps(path: Path) -> None:
    """Refuse a file whose HDF5 global heap collections the HDF5 library would loop on forever.

    Variable-length strings (the 'format' attribute, 'mesh_names') live in global heap
    collections ("GCOL" blocks). HDF5 walks a collection's objects by their stored sizes; a
    free-space object (index 0) of size 0 does not advance the walk, and the library spins
    in C, where no timeout or signal reaches it. Walking the same way here first is cheap
    (one scan for the signature) and turns that damage into a FormatError.
    """
    import mmap

    with open(path, "rb") as file:
        if path.stat().st_size == 0:
            return
        with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
            length_size = _superblock_length_size(data)
            start = data.find(b"GCOL")
            while start >= 0:
                if not _global_heap_walk_ends(data, start, length_size):
                    raise FormatError(
                        f"{path}: not a readable HDF5 trajectory file (damaged global heap at byte {start})"
                    )
                start = data.find(b"GCOL", start + 4)


def _superblock_length_size(data) -> int:
    """Bytes per 'length' field, from the superblock at byte 0 (8, h5py's, when unreadable)."""
    if data[:8] != b"\x89HDF\r\n\x1a\n" or len(data) < 16:
        return 8
    size = data[14] if data[8] in (0, 1) else data[10]
    return size if size in (2, 4, 8) else 8


GLOBAL_HEAP_MIN_SIZE = 4096
"""HDF5 allocates global heap collections of at least this many bytes (H5HG_MINSIZE)."""


def _global_heap_walk_ends(data, start: int, length_size: int) -> bool:
    """Walk the collection at `start` as HDF5's H5HG__cache_heap_deserialize does: True when
    every step advances and stays inside the collection, or the bytes at `start` are no
    collection header (version 1, three reserved zero bytes, a size from 4096 bytes to the end
    of the file): a file whose data happens to hold "GCOL" is not refused for it."""
    header = 8 + length_size
    if start + header > len(data) or data[start + 4 : start + 8] != b"\x01\x00\x00\x00":
        return True
    end = start + int.from_bytes(data[start + 8 : start + header], "little")
    if not GLOBAL_HEAP_MIN_SIZE <= end - start <= len(data) - start:
        return True  # not a collection's header: the same bytes inside a dataset or attribute
    object_header = 8 + length_size
    position = start + header
    while position < min(end, len(data)):
        if position + object_header > end:
            return True  # a tail too small for an object header is free space
        index = int.from_bytes(data[position : position + 2], "little")
        size = int.from_bytes(data[position + 8 : position + object_header], "little")
        step = object_header + (size + 7) // 8 * 8 if index > 0 else size
        if step == 0 or position + step > end:
            return False
        position += step
    return True


def _read_open_file(f, where: str, trajectory_ids) -> TrajectoryFile:
    _check_header(f, where)
    meshes = {name: _read_mesh(f["meshes"][name], f"{where}: mesh {name!r}") for name in f["meshes"]}
    if "trajectories" not in f:
        raise FormatError(f"{where}: missing group 'trajectories'")
    group = f["trajectories"]
    ids = list(group.keys()) if trajectory_ids is None else [str(i) for i in trajectory_ids]
    trajectories = {}
    for key in ids:
        if key not in group:
            raise FormatError(f"{where}: no trajectory {key!r} (the file has {len(group)})")
        trajectories[key] = _read_one(group[key], f"{where}: trajectory {key!r}")
    known = {"format", "format_version", "dt", "gravity"}
    attrs = {k: _plain(v) for k, v in f.attrs.items() if k not in known and _is_plain(v)}
    return TrajectoryFile(
        dt=float(f.attrs["dt"]),
        gravity=np.asarray(f.attrs["gravity"], np.float64).reshape(-1),
        meshes=meshes,
        trajectories=trajectories,
        attrs=attrs,
    )


def _check_header(f, where: str) -> None:
    fmt = _plain(f.attrs.get("format", None))
    if fmt != FORMAT:
        raise FormatError(f"{where}: attribute 'format' is {fmt!r}, expected {FORMAT!r}")
    version = _plain(f.attrs.get("format_version", None))
    if not isinstance(version, int) or version not in SUPPORTED_VERSIONS:
        raise FormatError(
            f"{where}: format_version {version!r} is not supported (this fignetctl reads "
            f"{', '.join(map(str, SUPPORTED_VERSIONS))}); upgrade fignetctl or convert the file"
        )
    for attr in ("dt", "gravity"):
        if attr not in f.attrs:
            raise FormatError(f"{where}: missing root attribute {attr!r}")
    if "meshes" not in f:
        raise FormatError(f"{where}: missing group 'meshes'")


def _read_mesh(group, where: str) -> Mesh:
    for field in ("vertices", "faces"):
        if field not in group:
            raise FormatError(f"{where}: missing field {field!r}")
    return Mesh(vertices=_read_dataset(group, "vertices", where), faces=_read_dataset(group, "faces", where))


def _read_one(group, where: str) -> Trajectory:
    required = ["mesh_names", *_FRAME_FIELDS, *_OBJECT_FIELDS]
    for field in required:
        if field not in group:
            raise FormatError(f"{where}: missing field {field!r}")
    names = np.array(
        [_plain(n) for n in np.atleast_1d(_read_dataset(group, "mesh_names", where))], dtype=object
    )
    values = {field: _read_dataset(group, field, where) for field in required[1:]}
    velocities = {field: _read_dataset(group, field, where) for field in VELOCITY_FIELDS if field in group}
    known = {*required, *VELOCITY_FIELDS}
    extras = {k: _read_dataset(group, k, where) for k in group if k not in known}
    return Trajectory(mesh_names=names, extras=extras, **values, **velocities)


# Deflate (gzip) compresses at most ~1032:1, so a dataset far larger than its stored bytes is
# mostly never-written chunks: a damaged or hostile shape, not data.
_MOST_EXPANSION = 1100
_SMALL_DATASET_BYTES = 1 << 20


def _read_dataset(group, field: str, where: str) -> np.ndarray:
    """group[field] as an array, after checking that it is a dataset of a plausible size."""
    import h5py

    dataset = group[field]
    if not isinstance(dataset, h5py.Dataset):
        raise FormatError(f"{where}: {field!r} is not a dataset")
    nbytes = int(np.prod(dataset.shape, dtype=np.float64) * dataset.dtype.itemsize) if dataset.shape else 0
    if nbytes > _SMALL_DATASET_BYTES and nbytes > _MOST_EXPANSION * dataset.id.get_storage_size():
        raise FormatError(
            f"{where}: field {field!r} claims shape {dataset.shape} but the file stores almost none of it"
        )
    return dataset[()]


def _is_plain(value) -> bool:
    """Whether an extra root attribute is text or numbers (kept in TrajectoryFile.attrs);
    object references, opaque and compound values are left out."""
    if isinstance(value, (str, bytes, int, float, bool)):
        return True
    return isinstance(value, (np.generic, np.ndarray)) and value.dtype.kind in "biufcSU"


def _plain(value):
    """h5py gives bytes or numpy scalars for attributes; make them plain Python."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.generic):
        return value.item()
    return value


# Bounds on the physical values a file may hold: beyond them a simulation over- or underflows
# (a frame rate of 1e300, a mass of 1e30) long before it could mean anything.
DT_RANGE = (1e-6, 100.0)  # seconds between frames
MAX_SCALE = 1e4
MAX_MASS = 1e9  # kg
MAX_MATERIAL = 1e3  # friction, restitution


def _validate(data: TrajectoryFile, where: str) -> None:
    if not (np.isfinite(data.dt) and DT_RANGE[0] <= data.dt <= DT_RANGE[1]):
        raise FormatError(
            f"{where}: 'dt' must be between {DT_RANGE[0]:g} and {DT_RANGE[1]:g} seconds, got {data.dt}"
        )
    gravity = np.asarray(data.gravity)
    if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
        raise FormatError(f"{where}: 'gravity' must be 3 finite numbers, got {gravity.tolist()}")
    for name, mesh in data.meshes.items():
        _validate_mesh(mesh, f"{where}: mesh {name!r}")
    if not data.trajectories:
        raise FormatError(f"{where}: the file holds no trajectories")
    for key, trajectory in data.trajectories.items():
        _validate_trajectory(trajectory, data.meshes, f"{where}: trajectory {key!r}")


def _validate_mesh(mesh: Mesh, where: str) -> None:
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.dtype.kind != "f":
        raise FormatError(
            f"{where}: field 'vertices' must be (V, 3) float, got {vertices.shape} {vertices.dtype}"
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.dtype.kind not in "iu":
        raise FormatError(f"{where}: field 'faces' must be (F, 3) int, got {faces.shape} {faces.dtype}")
    if len(faces) == 0:
        raise FormatError(f"{where}: field 'faces' is empty")
    if not np.all(np.isfinite(vertices)):
        raise FormatError(f"{where}: field 'vertices' holds non-finite numbers")
    outside = faces[(faces < 0) | (faces >= len(vertices))]
    if outside.size:
        raise FormatError(
            f"{where}: field 'faces' refers to vertex {int(outside[0])}, but the mesh has {len(vertices)} vertices"
        )


def _validate_trajectory(t: Trajectory, meshes: dict, where: str) -> None:
    positions, quaternions = np.asarray(t.positions), np.asarray(t.quaternions)
    if positions.ndim != 3 or positions.shape[2] != 3 or positions.shape[0] < 1:
        raise FormatError(f"{where}: field 'positions' must be (T, O, 3), got {positions.shape}")
    frames, objects = positions.shape[:2]
    if quaternions.shape != (frames, objects, 4):
        raise FormatError(
            f"{where}: field 'quaternions' must be {(frames, objects, 4)}, got {quaternions.shape}"
        )
    for field, value in (("positions", positions), ("quaternions", quaternions)):
        if value.dtype.kind != "f":
            raise FormatError(f"{where}: field {field!r} must be float, got {value.dtype}")
        bad = ~np.isfinite(value)
        if bad.any():
            frame, obj = np.argwhere(bad)[0][:2]
            raise FormatError(f"{where}: field {field!r} is not finite at frame {frame}, object {obj}")
    _validate_velocities(t, where)
    norms = np.linalg.norm(quaternions.astype(np.float64), axis=-1)
    off = np.abs(norms - 1.0) > QUATERNION_TOLERANCE
    if off.any():
        frame, obj = np.argwhere(off)[0]
        raise FormatError(
            f"{where}: field 'quaternions' is not a unit quaternion at frame {frame}, object {obj} "
            f"(norm {norms[frame, obj]:.6f})"
        )
    _validate_objects(t, meshes, objects, where)


def _validate_velocities(t: Trajectory, where: str) -> None:
    present = [field for field in VELOCITY_FIELDS if getattr(t, field) is not None]
    if len(present) == 1:
        missing = next(field for field in VELOCITY_FIELDS if field not in present)
        raise FormatError(f"{where}: has {present[0]!r} but not {missing!r}; give both or neither")
    for field in present:
        value = np.asarray(getattr(t, field))
        if value.shape != t.positions.shape or value.dtype.kind != "f":
            raise FormatError(
                f"{where}: field {field!r} must be float {tuple(t.positions.shape)}, got {value.shape} {value.dtype}"
            )
        bad = ~np.isfinite(value)
        if bad.any():
            frame, obj = np.argwhere(bad)[0][:2]
            raise FormatError(f"{where}: field {field!r} is not finite at frame {frame}, object {obj}")


def _validate_objects(t: Trajectory, meshes: dict, objects: int, where: str) -> None:
    names = np.asarray(t.mesh_names)
    if names.shape != (objects,):
        raise FormatError(f"{where}: field 'mesh_names' must be ({objects},), got {names.shape}")
    missing = sorted({str(n) for n in names} - set(meshes))
    if missing:
        raise FormatError(f"{where}: field 'mesh_names' names meshes not in /meshes: {', '.join(missing)}")
    for field, (kind, _) in _OBJECT_FIELDS.items():
        value = np.asarray(getattr(t, field))
        if value.shape != (objects,):
            raise FormatError(f"{where}: field {field!r} must be ({objects},), got {value.shape}")
        if kind == "f" and (value.dtype.kind not in "fiu" or not np.all(np.isfinite(value))):
            raise FormatError(f"{where}: field {field!r} must hold finite numbers")
        if kind == "b" and value.dtype.kind not in "biu":
            raise FormatError(f"{where}: field {field!r} must be boolean, got {value.dtype}")
    if np.any(np.asarray(t.scales) <= 0) or np.any(np.asarray(t.scales) > MAX_SCALE):
        raise FormatError(f"{where}: field 'scales' must be positive and at most {MAX_SCALE:g}")
    for field, largest in (("mass", MAX_MASS), ("friction", MAX_MATERIAL), ("restitution", MAX_MATERIAL)):
        value = np.asarray(getattr(t, field))
        if np.any(value < 0) or np.any(value > largest):
            raise FormatError(f"{where}: field {field!r} must be between 0 and {largest:g}")
