"""Trajectory files as scenes the simulator reads: concatenated geometry plus poses.

The model sees each mesh decimated (quadric error metrics) to at most `max_faces` faces in the
same object frame, so poses are unchanged and FIGNet*'s graph stays small; the decimated
meshes are made once per mesh name.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fignetctl.core.model.scene_graph import SceneGeometry, scene_geometry
from fignetctl.core.trajectory import TrajectoryFile, read_trajectories


@dataclasses.dataclass
class Scene:
    """One trajectory ready for the simulator.

    geometry : SceneGeometry of its objects (decimated meshes)
    positions : (T, O, 3) float64, quaternions : (T, O, 4) float64 (w x y z)
    """

    name: str
    geometry: SceneGeometry
    positions: np.ndarray
    quaternions: np.ndarray


def decimated_mesh(vertices, faces, max_faces):
    """(V, 3), (F, 3) -> the mesh with at most `max_faces` faces (unchanged if already so)."""
    if max_faces is None or len(faces) <= max_faces:
        return np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    simplified = mesh.simplify_quadric_decimation(face_count=int(max_faces))
    simplified.remove_unreferenced_vertices()
    return np.asarray(simplified.vertices, np.float64), np.asarray(simplified.faces, np.int64)


def scene_from_trajectory(data: TrajectoryFile, trajectory_id, max_faces, mesh_cache=None) -> Scene:
    """The Scene of one trajectory of a file; `mesh_cache` (name -> mesh) is filled and reused."""
    mesh_cache = {} if mesh_cache is None else mesh_cache
    trajectory = data.trajectories[trajectory_id]
    for name in trajectory.mesh_names:
        if name not in mesh_cache:
            mesh = data.meshes[name]
            mesh_cache[name] = decimated_mesh(mesh.vertices, mesh.faces, max_faces)
    properties = np.stack([trajectory.mass, trajectory.friction, trajectory.restitution], axis=1)
    geometry = scene_geometry(
        [mesh_cache[name] for name in trajectory.mesh_names],
        trajectory.scales,
        trajectory.static,
        properties,
    )
    positions = np.asarray(trajectory.positions, np.float64)
    quaternions = np.asarray(trajectory.quaternions, np.float64)
    return Scene(str(trajectory_id), geometry, positions, quaternions)


def scenes_from_file(path, max_faces) -> list[Scene]:
    """Every trajectory of a file as a Scene (needs at least 3 frames each for training)."""
    data = read_trajectories(path)
    cache = {}
    return [scene_from_trajectory(data, key, max_faces, cache) for key in data.trajectories]
