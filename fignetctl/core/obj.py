"""Wavefront OBJ, the one place that reads and writes it (positions and triangles only).

Readers: `load_obj` (a checked trimesh.Trimesh: what build-graph accepts from users),
`read_obj` (vertices and triangles, polygons fanned as PyBullet's loader does),
`read_obj_groups` (the vertices of each `o`/`g` group: PyBullet makes one convex hull of each)
and `read_obj_vertices`. Writers are atomic: `write_obj` (one mesh) and
`write_convex_parts_obj` (one `o` group per convex part, PyBullet's compound collision shape).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fignetctl.core.atomic import atomic_path
from fignetctl.errors import FignetError


def _parse(path) -> tuple[np.ndarray, list[list[list[int]]]]:
    """(V, 3) vertices and, per group, its faces as 0-based corner lists (negative indices resolved)."""
    vertices, groups = [], []
    for line in Path(path).read_text(errors="replace").splitlines():
        if line.startswith("v "):
            vertices.append([float(value) for value in line.split()[1:4]])
        elif line.startswith(("o ", "g ")):
            groups.append([])
        elif line.startswith("f "):
            if not groups:
                groups.append([])
            corners = [int(token.split("/")[0]) for token in line.split()[1:]]
            groups[-1].append([c - 1 if c > 0 else len(vertices) + c for c in corners])
    return np.asarray(vertices, np.float64).reshape(-1, 3), groups


def read_obj(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float and triangles (F, 3) int64; FignetError when it holds none."""
    vertices, groups = _parse(path)
    faces = [
        [corners[0], corners[i], corners[i + 1]]
        for group in groups
        for corners in group
        for i in range(1, len(corners) - 1)
    ]
    if len(vertices) == 0 or not faces:
        raise FignetError(f"{path}: no triangles in this OBJ file")
    return vertices, np.array(faces, np.int64)


def read_obj_groups(path) -> list[np.ndarray]:
    """The vertices used by the faces of each `o`/`g` group, one (n_i, 3) array per group."""
    vertices, groups = _parse(path)
    return [vertices[np.unique(np.concatenate(group))] for group in groups if group]


def read_obj_vertices(path) -> np.ndarray:
    """(n, 3) float: every `v` line."""
    return _parse(path)[0]


def load_obj(path):
    """An .obj file -> trimesh.Trimesh (vertices and faces as written); a FignetError when it
    is unreadable, empty, non-finite, indexes missing vertices or has no face with an area."""
    import trimesh

    try:
        mesh = trimesh.load(path, file_type="obj", force="mesh", process=False)
    except Exception as error:  # trimesh raises many types for damaged files
        raise FignetError(f"{path}: not a readable .obj mesh ({type(error).__name__})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise FignetError(f"{path}: holds no triangles")
    _check_geometry(mesh, path)
    return mesh


def _check_geometry(mesh, path) -> None:
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise FignetError(f"{path}: vertices must have 3 coordinates and faces 3 corners")
    if not np.all(np.isfinite(vertices)) or np.abs(vertices).max() > np.finfo(np.float32).max:
        raise FignetError(f"{path}: holds vertices that are NaN, infinite or beyond float32")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise FignetError(f"{path}: a face refers to a vertex that does not exist")
    corners = vertices[faces]
    areas = 0.5 * np.linalg.norm(
        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1
    )
    if not np.any(areas > 0):
        raise FignetError(f"{path}: every triangle has zero area")


def write_obj(path, vertices, faces) -> Path:
    """One mesh (vertices (V, 3), triangles (F, 3) 0-based), written atomically."""
    lines = ["v %.9g %.9g %.9g" % tuple(vertex) for vertex in np.asarray(vertices, np.float64)]
    lines += ["f %d %d %d" % tuple(face) for face in np.asarray(faces, np.int64) + 1]
    with atomic_path(path) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    return Path(path)


def convex_parts_obj_text(convex_parts) -> str:
    """Per part an `o part_i` line, its convex hull's vertices and triangles."""
    from scipy.spatial import ConvexHull

    lines, offset = [], 1
    for index, part in enumerate(convex_parts):
        hull = ConvexHull(np.asarray(part, np.float64), qhull_options="QJ")  # joggled: flat parts too
        points = hull.points[hull.vertices]
        remap = np.zeros(len(hull.points), np.int64)
        remap[hull.vertices] = np.arange(len(hull.vertices)) + offset
        lines.append(f"o part_{index}")
        lines += ["v %.9g %.9g %.9g" % tuple(point) for point in points]
        lines += ["f %d %d %d" % tuple(face) for face in remap[hull.simplices]]
        offset += len(points)
    return "\n".join(lines) + "\n"


def write_convex_parts_obj(convex_parts, path) -> Path:
    """convex_parts_obj_text written atomically (worker processes may write the same file at once)."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(convex_parts_obj_text(convex_parts))
    return Path(path)
