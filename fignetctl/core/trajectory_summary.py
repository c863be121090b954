"""What a trajectory file holds, and how its objects move: counts, properties, energy.

`summarize` turns a `TrajectoryFile` into a plain, JSON-ready dict; `format_summary` makes
a readable text table from it. Energies are per frame and summed over the dynamic objects:

- translational kinetic ½·m·|v|², v from central finite differences of the positions
  (second order at the ends too, so exact for a free fall);
- rotational kinetic ½·ωᵀ·I_world·ω, ω from central differences of the quaternions and
  I the inertia of the scaled mesh filled uniformly with the object's mass;
- potential −m·g·p (m·10·z for gravity (0, 0, −10)).

Static objects (floor, environment) are counted but carry no energy.
"""

from __future__ import annotations

import numpy as np

from fignetctl.core.trajectory import Trajectory, TrajectoryFile
from fignetctl.core.transforms import lowest_vertex_heights as object_lowest_heights
from fignetctl.core.transforms import quat_multiply, quat_to_matrix, quat_to_rotation_vector, transform_points

ENERGY_TERMS = ("kinetic_translational", "kinetic_rotational", "potential", "total")


# ----------------------------------------------------------------------------- geometry


def mesh_inertia(vertices: np.ndarray, faces: np.ndarray, scale: float, mass: float) -> np.ndarray:
    """Inertia tensor (3, 3) of the mesh scaled by `scale`, filled uniformly with `mass`.

    For a mesh of volume V and unit-density inertia J (trimesh), scaling by s and setting
    the density to m / (s³V) gives I = m·s²·J / V. The sign of V and J flips together for
    an inside-out mesh, so their ratio is still right. A mesh that encloses no volume
    (open, flat) falls back to point masses at its vertices.
    """
    import trimesh

    vertices = np.asarray(vertices, np.float64)
    triangles = vertices[np.asarray(faces)]
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat mesh divides by a zero volume
        properties = trimesh.triangles.mass_properties(triangles, density=1.0)
    extent = np.ptp(vertices, axis=0)
    if abs(properties.volume) > 1e-9 * max(float(np.prod(extent)), 1e-30):
        return mass * scale**2 * np.asarray(properties.inertia) / properties.volume
    centred = vertices - vertices.mean(axis=0)
    covariance = centred.T @ centred / len(centred)
    return mass * scale**2 * (np.trace(covariance) * np.eye(3) - covariance)


def world_vertices(data: TrajectoryFile, trajectory_id, frame: int) -> list:
    """World vertices of every object of one trajectory at one frame.

    Returns a list of (V_o, 3) float64 arrays, one per object: R(q)·(scale·v) + p.
    """
    trajectory = data.trajectories[str(trajectory_id)]
    return [
        transform_points(
            data.meshes[str(name)].vertices,
            float(trajectory.scales[index]),
            trajectory.positions[frame, index],
            trajectory.quaternions[frame, index],
        )
        for index, name in enumerate(trajectory.mesh_names)
    ]


# ----------------------------------------------------------------------------- motion


def linear_velocities(positions: np.ndarray, dt: float) -> np.ndarray:
    """positions : (T, O, 3) -> (T, O, 3) velocities by central differences.

    Second-order one-sided differences at the ends (exact for constant acceleration);
    first order for 2 frames; zero for a single frame.
    """
    positions = np.asarray(positions, np.float64)
    if len(positions) < 2:
        return np.zeros_like(positions)
    return np.gradient(positions, dt, axis=0, edge_order=2 if len(positions) >= 3 else 1)


def angular_velocities(quaternions: np.ndarray, dt: float) -> np.ndarray:
    """quaternions : (T, O, 4) w x y z -> (T, O, 3) world-frame angular velocities (rad/s).

    ω_t = rotvec(q_{t+1} ⊗ q_{t-1}⁻¹) / (2·dt); one-sided at the ends. Exact for a
    constant angular velocity below π / (2·dt).
    """
    quaternions = np.asarray(quaternions, np.float64)
    frames = len(quaternions)
    if frames < 2:
        return np.zeros(quaternions.shape[:-1] + (3,))
    index = np.arange(frames)
    after, before = np.minimum(index + 1, frames - 1), np.maximum(index - 1, 0)
    inverse_before = quaternions[before] * np.array([1.0, -1.0, -1.0, -1.0])
    delta = quat_multiply(quaternions[after], inverse_before)
    span = ((after - before) * dt)[:, None, None]
    return quat_to_rotation_vector(delta) / span


def body_inertias(data: TrajectoryFile, trajectory: Trajectory) -> np.ndarray:
    """(O, 3, 3) inertia of each object in its object frame; zeros for static objects."""
    inertias = np.zeros((trajectory.num_objects, 3, 3))
    for index, name in enumerate(trajectory.mesh_names):
        if trajectory.static[index] or trajectory.mass[index] <= 0:
            continue
        mesh = data.meshes[str(name)]
        inertias[index] = mesh_inertia(
            mesh.vertices, mesh.faces, float(trajectory.scales[index]), float(trajectory.mass[index])
        )
    return inertias


def energies(data: TrajectoryFile, trajectory: Trajectory) -> dict:
    """Per-frame energies in joules summed over dynamic objects: ENERGY_TERMS -> (T,)."""
    dynamic = ~np.asarray(trajectory.static, bool)
    mass = np.where(dynamic, np.asarray(trajectory.mass, np.float64), 0.0)
    velocity = linear_velocities(trajectory.positions, data.dt)
    omega = angular_velocities(trajectory.quaternions, data.dt)
    rotations = quat_to_matrix(trajectory.quaternions)
    omega_body = np.einsum("toji,toj->toi", rotations, omega)
    inertia = body_inertias(data, trajectory)
    translational = 0.5 * np.einsum("o,toi,toi->t", mass, velocity, velocity)
    rotational = 0.5 * np.einsum("toi,oij,toj->t", omega_body, inertia, omega_body)
    positions = np.asarray(trajectory.positions, np.float64)
    potential = -np.einsum("o,toi,i->t", mass, positions, np.asarray(data.gravity, np.float64))
    total = translational + rotational + potential
    return dict(zip(ENERGY_TERMS, (translational, rotational, potential, total)))


def lowest_vertex_heights(data: TrajectoryFile, trajectory: Trajectory) -> np.ndarray:
    """(T,) lowest world z of any dynamic object's vertices per frame (NaN if none moves)."""
    dynamic = np.flatnonzero(~np.asarray(trajectory.static, bool))
    if dynamic.size == 0:
        return np.full(trajectory.num_frames, np.nan)
    vertex_sets = [data.meshes[str(trajectory.mesh_names[o])].vertices for o in dynamic]
    positions = np.asarray(trajectory.positions, np.float64)[:, dynamic]
    scales = np.asarray(trajectory.scales, np.float64)[dynamic]
    per_object = object_lowest_heights(positions, trajectory.quaternions[:, dynamic], scales, vertex_sets)
    return per_object.min(axis=1)


# ----------------------------------------------------------------------------- summary


def _object_rows(data: TrajectoryFile, trajectory: Trajectory, speeds: np.ndarray) -> list:
    rows = []
    for index, name in enumerate(trajectory.mesh_names):
        mesh = data.meshes[str(name)]
        rows.append(
            {
                "index": index,
                "mesh": str(name),
                "static": bool(trajectory.static[index]),
                "scale": float(trajectory.scales[index]),
                "mass": float(trajectory.mass[index]),
                "friction": float(trajectory.friction[index]),
                "restitution": float(trajectory.restitution[index]),
                "vertices": len(mesh.vertices),
                "faces": len(mesh.faces),
                "max_speed": float(speeds[:, index].max()),
                "final_speed": float(speeds[-1, index]),
            }
        )
    return rows


def summarize_trajectory(data: TrajectoryFile, trajectory_id) -> dict:
    """Objects, per-frame energy, speeds and lowest vertex height of one trajectory."""
    trajectory = data.trajectories[str(trajectory_id)]
    dynamic = ~np.asarray(trajectory.static, bool)
    speeds = np.linalg.norm(linear_velocities(trajectory.positions, data.dt), axis=-1)
    speeds[:, ~dynamic] = 0.0
    lowest = lowest_vertex_heights(data, trajectory)
    return {
        "id": str(trajectory_id),
        "frames": trajectory.num_frames,
        "duration_s": float((trajectory.num_frames - 1) * data.dt),
        "objects": trajectory.num_objects,
        "dynamic_objects": int(dynamic.sum()),
        "max_speed": float(speeds.max()),
        "object_table": _object_rows(data, trajectory, speeds),
        "energy": {key: value.tolist() for key, value in energies(data, trajectory).items()},
        "lowest_vertex_z": [None if np.isnan(z) else float(z) for z in lowest],
    }


def summarize(data: TrajectoryFile) -> dict:
    """A JSON-ready summary of a whole trajectory file: counts, then one entry per trajectory."""
    trajectories = [summarize_trajectory(data, key) for key in data.trajectories]
    return {
        "dt": float(data.dt),
        "fps": float(1.0 / data.dt),
        "gravity": [float(g) for g in data.gravity],
        "meshes": len(data.meshes),
        "trajectories": len(trajectories),
        "frames": sum(t["frames"] for t in trajectories),
        "objects": sum(t["objects"] for t in trajectories),
        "per_trajectory": trajectories,
    }


# ----------------------------------------------------------------------------- text


def _file_lines(summary: dict) -> list:
    frames = sorted({t["frames"] for t in summary["per_trajectory"]})
    frame_text = str(frames[0]) if len(frames) == 1 else f"{frames[0]}–{frames[-1]}"
    gravity = ", ".join(f"{g:g}" for g in summary["gravity"])
    return [
        f"dt {summary['dt']:.6g} s ({summary['fps']:.4g} fps), gravity ({gravity}) m/s²",
        f"{summary['trajectories']} trajectories, {summary['frames']} frames in all "
        f"({frame_text} each), {summary['objects']} objects in all, {summary['meshes']} meshes",
    ]


def _energy_line(trajectory: dict) -> str:
    total = trajectory["energy"]["total"]
    change = total[-1] - total[0]
    heights = [z for z in trajectory["lowest_vertex_z"] if z is not None]
    lowest = f", lowest vertex z {min(heights):.3f} m" if heights else ""
    return (
        f"  energy {total[0]:.4g} J -> {total[-1]:.4g} J ({change:+.3g} J), "
        f"max speed {trajectory['max_speed']:.3g} m/s{lowest}"
    )


_COLUMNS = (
    ("#", "index", "{:>3}"),
    ("mesh", "mesh", "{:<12}"),
    ("static", "static", "{!s:<6}"),
    ("scale", "scale", "{:>6.3f}"),
    ("mass kg", "mass", "{:>8.3f}"),
    ("frict", "friction", "{:>5.2f}"),
    ("rest", "restitution", "{:>5.2f}"),
    ("verts", "vertices", "{:>6}"),
    ("faces", "faces", "{:>6}"),
    ("max m/s", "max_speed", "{:>8.3f}"),
    ("final m/s", "final_speed", "{:>9.3f}"),
)


def _object_table_lines(rows: list) -> list:
    def widths_of(cells):
        return [max(len(header), len(cell)) for (header, _, _), cell in zip(_COLUMNS, cells)]

    body = [[fmt.format(row[key]) for _, key, fmt in _COLUMNS] for row in rows]
    widths = [max(w) for w in zip(*(widths_of(cells) for cells in body))] if body else []
    header = "  ".join(h.rjust(w) for (h, _, _), w in zip(_COLUMNS, widths))
    lines = ["    " + header]
    lines += ["    " + "  ".join(c.rjust(w) for c, w in zip(cells, widths)) for cells in body]
    return lines


def format_summary(summary: dict) -> str:
    """A readable text report of `summarize`'s dict: the file, then a table per trajectory."""
    lines = _file_lines(summary)
    for trajectory in summary["per_trajectory"]:
        lines.append("")
        lines.append(
            f"trajectory {trajectory['id']}: {trajectory['frames']} frames "
            f"({trajectory['duration_s']:.3g} s), {trajectory['objects']} objects "
            f"({trajectory['dynamic_objects']} dynamic)"
        )
        lines.append(_energy_line(trajectory))
        lines.extend(_object_table_lines(trajectory["object_table"]))
    return "\n".join(lines) + "\n"
