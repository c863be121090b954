"""Trajectory files as scenes the simulator reads: concatenated geometry plus poses.

The model sees each dynamic object's mesh decimated (quadric error metrics; `decimated_mesh`)
to at most `max_faces_per_object` faces in the same object frame, so poses are unchanged and FIGNet*'s
graph stays small. Static meshes are not decimated: a static face far from every moving object
costs nothing (the broad phase keeps static faces cached), and decimating an environment mesh
tears holes in it (the main job's tray, 1002 faces cut to 256, lost the floor under the ball,
which fell through). Static meshes are instead subdivided until no edge is longer than `max_static_edge` metres, so that a
floor is made of faces the size of an object's rather than of two huge triangles (the
face–face features and their normalizer see vertex offsets). Prepared meshes are made once
per mesh name (and scale, for static ones).

When the whole trajectory is known (training, evaluation), static faces farther than
`static_reach` from every place the dynamic objects visit are dropped: they can never be in a
collision pair of a ground-truth frame, so the training graphs are exactly those of the whole
floor, at the cost of a few thousand faces instead of hundreds of thousands.
"""

from __future__ import annotations

import collections
import collections.abc
import dataclasses

import numpy as np

from fignetctl.core.model.scene_graph import SceneGeometry, scene_geometry
from fignetctl.core.model.trained_ranges import largest_side, largest_sides
from fignetctl.core.trajectory import TrajectoryFile, estimated_velocities, read_trajectories


@dataclasses.dataclass
class Scene:
    """One trajectory ready for the simulator.

    geometry : SceneGeometry of its objects (decimated meshes)
    positions : (T, O, 3) float64, quaternions : (T, O, 4) float64 (w x y z)
    dt : seconds between frames
    velocities, angular_velocities : (T, O, 3) float64 m/s and rad/s at each frame, recorded,
        or, when not given, estimated from the frames (`velocities_recorded` says which)
    """

    name: str
    geometry: SceneGeometry
    positions: np.ndarray
    quaternions: np.ndarray
    dt: float = 1 / 30
    velocities: np.ndarray | None = None
    angular_velocities: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.velocities_recorded = self.velocities is not None
        if not self.velocities_recorded:
            self.velocities, self.angular_velocities = estimated_velocities(
                self.positions, self.quaternions, self.dt
            )


DECIMATIONS = ("closest", "quadric")
"""How `decimated_mesh` decimates (`SimulatorConfig.decimation`)."""
MIN_FACES = 4
"""The fewest faces a moving mesh may be decimated to (a tetrahedron's): `train`, `rollout` and
`evaluate` refuse fewer."""


DEVIATION_TOLERANCE = 0.01
"""'closest' decimation looks for a better mesh when quadric decimation moves the surface by
more than this fraction of the mesh's largest side."""


def decimated_mesh(vertices, faces, max_faces, method="closest"):
    """(V, 3), (F, 3) -> the mesh with at most `max_faces` faces (unchanged if already so).

    'quadric': quadric error decimation of the mesh as given. 'closest': the same, unless that
    moves the surface (`vertex_hausdorff`) by more than DEVIATION_TOLERANCE of the mesh's size;
    then the mesh is first reduced to the fewest faces that keep its surface
    (`surface_preserving`: a polyhedron subdivided for rendering, as the movi-b shapes are,
    gets its facets back), decimated from there if still too fine, and used if it deviates
    less. Quadric decimation of a finely subdivided polyhedron can collapse its thin parts: the
    movi-b mug (1888 faces, 2.0 across) cut to 256 faces so loses 43 % of its volume and
    deviates 0.69 from its surface, and a mug resting on the floor in PyBullet looked to the
    model up to 0.2 m into it; reduced first, it deviates 0.010 (the gear: 0.106, then 0.000).
    """
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if max_faces is None or len(faces) <= max_faces:
        return vertices, faces
    if method not in DECIMATIONS:
        raise ValueError(f"decimation must be one of {DECIMATIONS}, not {method!r}")
    direct = _quadric_decimation(vertices, faces, max_faces)
    if method == "quadric":
        return direct
    deviation = vertex_hausdorff((vertices, faces), direct)
    if deviation <= DEVIATION_TOLERANCE * float(np.ptp(vertices, axis=0).max()):
        return direct
    reduced = surface_preserving(vertices, faces)
    if reduced is None:
        return direct
    if len(reduced[1]) > max_faces:
        reduced = _quadric_decimation(*reduced, max_faces)
    return reduced if vertex_hausdorff((vertices, faces), reduced) < deviation else direct


def _quadric_decimation(vertices, faces, max_faces):
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    simplified = mesh.simplify_quadric_decimation(face_count=int(max_faces))
    simplified.remove_unreferenced_vertices()
    return np.asarray(simplified.vertices, np.float64), np.asarray(simplified.faces, np.int64)


SIMPLIFY_TOLERANCE = 1e-5
"""`surface_preserving` moves no surface by more than this fraction of the mesh's largest side."""


def surface_preserving(vertices, faces):
    """The mesh with the fewest faces whose surface is within SIMPLIFY_TOLERANCE of it (edges
    collapsed by manifold3d's `simplify`: coplanar subdivisions go, curved surfaces stay), or
    None when the mesh is not a closed manifold that manifold3d accepts."""
    import manifold3d

    mesh = manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(vertices, np.float64),
        tri_verts=np.ascontiguousarray(faces, np.uint64),
    )
    solid = manifold3d.Manifold(mesh)
    if solid.status() != manifold3d.Error.NoError or solid.is_empty():
        return None
    simplified = solid.simplify(SIMPLIFY_TOLERANCE * float(np.ptp(vertices, axis=0).max())).to_mesh64()
    return (
        np.array(simplified.vert_properties[:, :3], np.float64),  # a writable copy
        np.array(simplified.tri_verts, np.int64),
    )


def vertex_hausdorff(first, second) -> float:
    """The largest distance from a vertex of either (vertices, faces) mesh to the other's
    surface (a two-sided Hausdorff distance over the vertices)."""
    import trimesh

    largest = 0.0
    for (points, _), (vertices, faces) in ((first, second), (second, first)):
        surface = trimesh.Trimesh(vertices, faces, process=False)
        _, distances, _ = trimesh.proximity.closest_point(surface, points)
        largest = max(largest, float(distances.max(initial=0.0)))
    return largest


# Static faces kept around the dynamic objects' reach: in training the collision radius plus
# the input noise would do; evaluation rollouts may stray from the ground truth, so a
# prediction must be this far off before it could miss the floor.
TRAINING_STATIC_REACH = 1.0
EVALUATION_STATIC_REACH = 5.0


def subdivided_mesh(vertices, faces, max_edge):
    """(V, 3), (F, 3) -> the mesh with every face split (1 -> 4) until no edge is longer than
    `max_edge`; the surface is unchanged."""
    from trimesh.remesh import subdivide_to_size

    vertices, faces = subdivide_to_size(
        np.asarray(vertices, np.float64), np.asarray(faces, np.int64), max_edge, max_iter=64
    )
    return np.asarray(vertices, np.float64), np.asarray(faces, np.int64)


def mesh_settings(config) -> tuple:
    """The fields of a SimulatorConfig that `prepared_mesh` reads: two configs with the same
    ones read a file's scenes alike."""
    return config.max_faces_per_object, config.decimation, config.max_static_edge


def prepared_mesh(vertices, faces, static, scale, config):
    """A mesh as the simulator `config` sees it (unscaled, object frame; `mesh_settings`)."""
    if not static:
        vertices, faces = decimated_mesh(vertices, faces, config.max_faces_per_object, config.decimation)
    if static and config.max_static_edge is not None:
        vertices, faces = subdivided_mesh(vertices, faces, config.max_static_edge / float(scale))
    return vertices, faces


def scene_from_trajectory(
    data: TrajectoryFile, trajectory_id, config, mesh_cache=None, static_reach=None
) -> Scene:
    """The Scene of one trajectory of a file, its meshes prepared for a SimulatorConfig.

    mesh_cache : dict filled and reused across calls (prepared meshes by name)
    static_reach : metres, or None to keep all static faces (see the module docstring)
    """
    mesh_cache = {} if mesh_cache is None else mesh_cache
    trajectory = data.trajectories[trajectory_id]
    meshes = [
        _cached_mesh(data, name, static, scale, config, mesh_cache)
        for name, static, scale in zip(trajectory.mesh_names, trajectory.static, trajectory.scales)
    ]
    positions = np.asarray(trajectory.positions, np.float64)
    quaternions = np.asarray(trajectory.quaternions, np.float64)
    static = np.asarray(trajectory.static, bool)
    if static_reach is not None:
        meshes = _crop_static_meshes(meshes, trajectory.scales, static, positions, quaternions, static_reach)
    geometry = scene_geometry(meshes, trajectory.scales, static, trajectory.properties)
    velocities = [None, None]
    if trajectory.has_velocities:
        velocities = [
            np.asarray(trajectory.velocities, np.float64),
            np.asarray(trajectory.angular_velocities, np.float64),
        ]
    return Scene(str(trajectory_id), geometry, positions, quaternions, float(data.dt), *velocities)


def _cached_mesh(data, name, static, scale, config, cache):
    """`prepared_mesh` of the file's mesh `name`, made once per name (and scale, if static)."""
    key = (name, float(scale)) if static else name
    if key not in cache:
        mesh = data.meshes[name]
        cache[key] = prepared_mesh(mesh.vertices, mesh.faces, static, scale, config)
    return cache[key]


def _crop_static_meshes(meshes, scales, static, positions, quaternions, reach):
    """Drop the faces of unmoving static meshes whose box is farther than `reach` from the box
    swept by the dynamic objects (grown by their size) over all frames."""
    from fignetctl.core.transforms import quat_to_matrix

    dynamic = np.flatnonzero(~static)
    if len(dynamic) == 0:
        return meshes
    sizes = np.array(
        [np.linalg.norm(np.asarray(meshes[o][0]), axis=1).max() * float(scales[o]) for o in dynamic]
    )
    centres = positions[:, dynamic]
    lower = (centres - sizes[None, :, None]).reshape(-1, 3).min(axis=0) - reach
    upper = (centres + sizes[None, :, None]).reshape(-1, 3).max(axis=0) + reach
    cropped = list(meshes)
    for o in np.flatnonzero(static):
        if not (
            np.allclose(positions[:, o], positions[0, o])
            and np.allclose(quaternions[:, o], quaternions[0, o])
        ):
            continue  # a moving static object keeps its whole mesh
        vertices, faces = meshes[o]
        world = (
            np.asarray(vertices) * float(scales[o]) @ quat_to_matrix(quaternions[0, o]).T + positions[0, o]
        )
        triangles = world[faces]
        keep = ((triangles.max(axis=1) >= lower) & (triangles.min(axis=1) <= upper)).all(axis=1)
        if keep.all():
            continue
        used, new_faces = np.unique(faces[keep], return_inverse=True)
        cropped[o] = (np.asarray(vertices)[used], new_faces.reshape(-1, 3))
    return cropped


class SceneStore(collections.abc.Sequence):
    """The trajectories of a read file as Scenes, each made when first asked for and at most
    `capacity` kept (the least recently used go first; None keeps all).

    A made Scene holds float64 poses and the concatenated geometry of its objects, about six
    times the file's float32 arrays, and keeps more once a graph is built from it. Training
    draws scenes at random, so the store keeps the file's arrays for all and a bounded number
    of Scenes. It pickles without its Scenes: a graph-building worker gets the file's arrays and
    makes its own.
    """

    def __init__(self, data: TrajectoryFile, config, static_reach=None, capacity: int | None = None):
        if capacity is not None and capacity < 1:
            raise ValueError(f"capacity must be at least 1 or None, not {capacity}")
        self.data, self.config, self.static_reach, self.capacity = data, config, static_reach, capacity
        self.keys = list(data.trajectories)
        self._meshes = {}
        self._scenes = collections.OrderedDict()

    def __len__(self) -> int:
        return len(self.keys)

    def __getitem__(self, index) -> Scene:
        index = range(len(self.keys))[index]  # an IndexError out of range, as a list's
        scene = self._scenes.get(index)
        if scene is not None:
            self._scenes.move_to_end(index)
            return scene
        scene = scene_from_trajectory(
            self.data, self.keys[index], self.config, self._meshes, self.static_reach
        )
        self._scenes[index] = scene
        if self.capacity is not None and len(self._scenes) > self.capacity:
            self._scenes.popitem(last=False)
        return scene

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_scenes": collections.OrderedDict()}


def property_inputs(scenes) -> tuple[list, list]:
    """What `trained_ranges.property_ranges` reads of a list of Scenes or a SceneStore: each
    scene's ((O, 3) mass, friction, restitution, (O,) static) and (D,) `largest_sides` of its
    moving objects; a store's from the file's arrays and prepared meshes, without making Scenes."""
    if not isinstance(scenes, SceneStore):
        return (
            [(scene.geometry.properties, scene.geometry.static) for scene in scenes],
            [largest_sides(scene.geometry) for scene in scenes],
        )
    pairs, sides = [], []
    for key in scenes.keys:
        trajectory = scenes.data.trajectories[key]
        static = np.asarray(trajectory.static, bool)
        pairs.append((np.asarray(trajectory.properties, np.float64).reshape(len(static), 3), static))
        moving = [
            _cached_mesh(scenes.data, name, False, scale, scenes.config, scenes._meshes)[0] * float(scale)
            for name, scale in zip(trajectory.mesh_names[~static], trajectory.scales[~static])
        ]  # scaled as scene_geometry scales them
        sides.append(np.asarray([largest_side(rest) for rest in moving], np.float64))
    return pairs, sides


def frame_counts(scenes) -> list[int]:
    """The number of frames of each scene of a list or a SceneStore (whose Scenes it does not make)."""
    if isinstance(scenes, SceneStore):
        return [scenes.data.trajectories[key].num_frames for key in scenes.keys]
    return [scene.positions.shape[0] for scene in scenes]


def scenes_from_file(path, config, static_reach=None) -> list[Scene]:
    """Every trajectory of a file as a Scene (needs at least 3 frames each for training)."""
    return scenes_from_data(read_trajectories(path), config, static_reach)


def scenes_from_data(data: TrajectoryFile, config, static_reach=None) -> list[Scene]:
    """Every trajectory of a read file as a Scene."""
    cache = {}
    return [scene_from_trajectory(data, key, config, cache, static_reach) for key in data.trajectories]
