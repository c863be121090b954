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
    """Static properties of one object (paper table; FIGNet* defaults)."""

    mass: float
    friction: float
    restitution: float


ACTIVE = Properties(mass=1e-3, friction=0.5, restitution=0.5)
PASSIVE = Properties(mass=0.0, friction=0.5, restitution=0.3)


def drop_history(origin, drop_height=0.1, delta_z=0.01, start=None, velocity=None, dt=DT):
    """Positions (2, 3) of the object at frames t-1 and t.

    Default: start = origin raised by `drop_height`, and frame t-1 is Δz higher (a fall at
    Δz per frame). With `velocity` (3,) (world units / s): frame t-1 = start − velocity · dt.
    """
    start = np.asarray(origin, np.float64) + [0.0, 0.0, drop_height] if start is None else np.asarray(start, np.float64)
    step = np.array([0.0, 0.0, -delta_z]) if velocity is None else np.asarray(velocity, np.float64) * dt
    positions = np.stack([start - step, start])
    if not np.all(np.isfinite(positions)):
        raise FignetError("the start position and velocity must be finite numbers")
    return positions


def build_scene(object_mesh, environment_mesh, origin, positions, active=ACTIVE, passive=PASSIVE, duplicate=False,
                environment_origin=(0.0, 0.0, 0.0), dt=DT, gravity=GRAVITY) -> TrajectoryFile:
    """The scene file.

    object_mesh : (vertices (V, 3) relative to the object's origin, faces (F, 3))
    environment_mesh : (vertices (V, 3) relative to environment_origin, faces (F, 3))
    origin : (3,) the object's position at rest; positions : (2, 3) its frames t-1 and t
    duplicate : the moving object is a copy; the original stays at `origin`, static
    """
    meshes = {"environment": _mesh(*environment_mesh, "environment"), "object": _mesh(*object_mesh, "object")}
    names = ["environment", "object"]
    frames = [np.broadcast_to(np.asarray(environment_origin, np.float64), (2, 3)), positions]
    static, props = [True, False], [passive, active]
    if duplicate:
        names.insert(1, "object")
        frames.insert(1, np.broadcast_to(np.asarray(origin, np.float64), (2, 3)))
        static.insert(1, True)
        props.insert(1, Properties(0.0, active.friction, active.restitution))
    count = len(names)
    quaternions = np.zeros((2, count, 4), np.float32)
    quaternions[..., 0] = 1.0
    trajectory = Trajectory(
        mesh_names=np.array(names, dtype=object),
        scales=np.ones(count, np.float32),
        positions=np.stack(frames, axis=1).astype(np.float32),
        quaternions=quaternions,
        static=np.array(static),
        mass=np.array([p.mass for p in props], np.float32),
        friction=np.array([p.friction for p in props], np.float32),
        restitution=np.array([p.restitution for p in props], np.float32),
    )
    attrs = {"source": "fignetctl build-graph", "duplicate": bool(duplicate)}
    return TrajectoryFile(dt=float(dt), gravity=np.asarray(gravity, np.float64), meshes=meshes, trajectories={"scene": trajectory}, attrs=attrs)


def _mesh(vertices, faces, name):
    vertices, faces = np.asarray(vertices, np.float32), np.asarray(faces, np.int32)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise FignetError(f"the {name} mesh has no triangles")
    return Mesh(vertices, faces)


def lowest_point_clearance(object_vertices, positions, environment_vertices, environment_faces, environment_origin=(0, 0, 0)):
    """Height of the object's lowest vertex above the environment surface right under it, per
    frame: positions (T, 3) -> (T,) (nan where nothing is under it). Identity rotations only are
    assumed for the environment; the object's rotation is ignored (use for rest checks)."""
    import trimesh

    environment = trimesh.Trimesh(np.asarray(environment_vertices) + environment_origin, environment_faces, process=False)
    clearance = []
    for position in np.asarray(positions, np.float64).reshape(-1, 3):
        world = np.asarray(object_vertices, np.float64) + position
        lowest = world[np.argmin(world[:, 2])]
        origin = np.array([[lowest[0], lowest[1], environment.bounds[1][2] + 1.0]])
        hits, _, _ = environment.ray.intersects_location(origin, np.array([[0.0, 0.0, -1.0]]))
        below = hits[hits[:, 2] <= lowest[2] + 1.0] if len(hits) else hits
        clearance.append(lowest[2] - below[:, 2].max() if len(below) else np.nan)
    return np.array(clearance)
