"""`build-graph`: extracted meshes + physical properties + a drop history -> a 2-frame scene
(trajectory file) that `rollout` simulates (paper, "Building the Graph").

The object (active, dynamic) and the environment (passive, static) become two objects of one
trajectory. The history is the paper's drop: the object at its start position at frame t and
shifted up by Δz at frame t-1, i.e. falling at Δz per frame; or any start and velocity.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile
from fignetctl.errors import FignetError

DT = 1.0 / 30.0
"""Seconds per frame of the bundled models (make-dataset's default --fps 30, what they were trained on)."""
GRAVITY = (0.0, 0.0, -10.0)


@dataclasses.dataclass(frozen=True)
class Properties:
    """Static properties of one object."""

    mass: float
    friction: float
    restitution: float


# Within what the bundled models were trained on (MOVi-B: moving objects friction 0.4/0.8,
# restitution 0.3/0.7, mass 0.2-59; the floor 0.3, 0.5): the active object is the paper's
# FIGNet row (mass 1, MOVi's rubber), the passive one MOVi's floor. The paper's FIGNet*
# row (active 1e-3, 0.5, 0.5; passive 0.5, 0.3) lies outside it, and the bundled FIGNet*
# lets a resting object slide on it (docs/build-graph.md, "Physical properties").
ACTIVE = Properties(mass=1.0, friction=0.8, restitution=0.7)
PASSIVE = Properties(mass=0.0, friction=0.3, restitution=0.5)


def drop_history(origin, drop_height=0.1, delta_z=0.01, start=None, velocity=None, dt=DT):
    """Positions (2, 3) of the object at frames t-1 and t.

    Default: start = origin raised by `drop_height`, and frame t-1 is Δz higher (a fall at
    Δz per frame). With `velocity` (3,) (world units / s): frame t-1 = start − velocity · dt.
    """
    start = (
        np.asarray(origin, np.float64) + [0.0, 0.0, drop_height]
        if start is None
        else np.asarray(start, np.float64)
    )
    step = np.array([0.0, 0.0, -delta_z]) if velocity is None else np.asarray(velocity, np.float64) * dt
    positions = np.stack([start - step, start])
    if not np.all(np.isfinite(positions)):
        raise FignetError("the start position and velocity must be finite numbers")
    return positions


def build_scene(
    object_mesh,
    environment_mesh,
    origin,
    positions,
    active=ACTIVE,
    passive=PASSIVE,
    duplicate=False,
    environment_origin=(0.0, 0.0, 0.0),
    dt=DT,
    gravity=GRAVITY,
) -> TrajectoryFile:
    """The scene file.

    object_mesh : (vertices (V, 3) relative to the object's origin, faces (F, 3))
    environment_mesh : (vertices (V, 3) relative to environment_origin, faces (F, 3))
    origin : (3,) the object's position at rest; positions : (2, 3) its frames t-1 and t, and its velocity
        (the same in both frames, no spin) is their difference / dt
    duplicate : the moving object is a copy; the original stays at `origin`, static, with the
        passive properties (it is part of the environment now)
    """
    meshes = {"environment": _mesh(*environment_mesh, "environment"), "object": _mesh(*object_mesh, "object")}
    names = ["environment", "object"]
    frames = [np.broadcast_to(np.asarray(environment_origin, np.float64), (2, 3)), positions]
    static, props = [True, False], [passive, active]
    if duplicate:
        names.insert(1, "object")
        frames.insert(1, np.broadcast_to(np.asarray(origin, np.float64), (2, 3)))
        static.insert(1, True)
        props.insert(1, passive)
    count = len(names)
    quaternions = np.zeros((2, count, 4), np.float32)
    quaternions[..., 0] = 1.0
    velocities = np.zeros((2, count, 3), np.float32)
    velocities[:, -1] = (np.asarray(positions[1], np.float64) - positions[0]) / dt  # the drop's, without spin
    trajectory = Trajectory(
        mesh_names=np.array(names, dtype=object),
        scales=np.ones(count, np.float32),
        positions=np.stack(frames, axis=1).astype(np.float32),
        quaternions=quaternions,
        static=np.array(static),
        mass=np.array([p.mass for p in props], np.float32),
        friction=np.array([p.friction for p in props], np.float32),
        restitution=np.array([p.restitution for p in props], np.float32),
        velocities=velocities,
        angular_velocities=np.zeros((2, count, 3), np.float32),
    )
    attrs = {"source": "fignetctl build-graph", "duplicate": bool(duplicate)}
    return TrajectoryFile(
        dt=float(dt),
        gravity=np.asarray(gravity, np.float64),
        meshes=meshes,
        trajectories={"scene": trajectory},
        attrs=attrs,
    )


def _mesh(vertices, faces, name):
    vertices, faces = np.asarray(vertices, np.float32), np.asarray(faces, np.int32)
    if (
        vertices.ndim != 2
        or vertices.shape[1] != 3
        or faces.ndim != 2
        or faces.shape[1] != 3
        or len(faces) == 0
    ):
        raise FignetError(f"the {name} mesh has no triangles")
    return Mesh(vertices, faces)


def drop_report(data, trajectory_id=None, rest_frames=10, rest_speed=0.02):
    """How a dropped object fared in a rollout file: per frame, the clearance of its lowest
    point above the static surface right under it (each vertex against the highest static face
    below it, vertical rays; negative = inside), and whether it came to rest.

    rest_speed : m/s; at rest when the object's fastest vertex moved slower over the last
        `rest_frames` frames
    returns dict: clearance_m (T,) list (nan where nothing is under it), min_clearance_m,
        final_speed_m_s, at_rest, rest_time_s (first frame after which it stays below
        rest_speed, or None)
    """
    import trimesh

    from fignetctl.core.transforms import transform_points

    key = next(iter(data.trajectories)) if trajectory_id is None else trajectory_id
    trajectory = data.trajectories[key]
    static = np.asarray(trajectory.static, bool)
    dynamic = np.flatnonzero(~static)
    if len(dynamic) != 1 or not static.any():
        raise FignetError(
            f"trajectory {key!r}: a drop has one moving object and a static environment "
            f"({len(dynamic)} moving, {int(static.sum())} static)"
        )
    obj = int(dynamic[0])
    frames = trajectory.num_frames
    surfaces = []
    for o in np.flatnonzero(static):
        mesh = data.meshes[trajectory.mesh_names[o]]
        world = transform_points(
            mesh.vertices, trajectory.scales[o], trajectory.positions[-1, o], trajectory.quaternions[-1, o]
        )
        surfaces.append(trimesh.Trimesh(world, mesh.faces, process=False))
    environment = trimesh.util.concatenate(surfaces)
    mesh = data.meshes[trajectory.mesh_names[obj]]
    vertices = np.stack(
        [
            transform_points(
                mesh.vertices,
                trajectory.scales[obj],
                trajectory.positions[t, obj],
                trajectory.quaternions[t, obj],
            )
            for t in range(frames)
        ]
    )  # (T, V, 3)
    top = environment.bounds[1][2] + 1.0
    points = vertices.reshape(-1, 3)
    origins = np.column_stack([points[:, :2], np.full(len(points), top)])
    hits, rays, _ = environment.ray.intersects_location(origins, np.tile([0.0, 0.0, -1.0], (len(points), 1)))
    surface = np.full(len(points), -np.inf)
    np.maximum.at(surface, rays, hits[:, 2])
    clearance = np.where(np.isfinite(surface), points[:, 2] - surface, np.nan).reshape(frames, -1)
    per_frame = np.array([np.nanmin(row) if np.isfinite(row).any() else np.nan for row in clearance])
    speeds = np.linalg.norm(np.diff(vertices, axis=0), axis=2).max(axis=1) / data.dt  # (T-1,)
    slow = speeds < rest_speed
    settled = next((t for t in range(len(slow)) if slow[t:].all()), None)
    return {
        "clearance_m": [None if not np.isfinite(c) else round(float(c), 5) for c in per_frame],
        "min_clearance_m": float(np.nanmin(per_frame)) if np.isfinite(per_frame).any() else None,
        "final_speed_m_s": float(speeds[-rest_frames:].max()),
        "at_rest": bool(slow[-rest_frames:].all()),
        "rest_time_s": None if settled is None else float(settled * data.dt),
        "dt": float(data.dt),
        "frames": int(frames),
    }
