"""MOVi-style ground truth: random tosses of rigid objects onto a floor, simulated with PyBullet.

The scenes follow Kubric's MOVi-B and MOVi-C workers (3-10 objects placed without overlap in
[(-5,-5,1), (5,5,5)] with a random rotation, tossed with a horizontal velocity
U((-4,-4,0), (4,4,0)) - (x, y, 0) toward the centre, onto a large static floor) and Kubric's
PyBullet settings (240 Hz, gravity (0, 0, -10), `restitutionVelocityThreshold=0,
warmStartingFactor=0, useSplitImpulse=True, contactSlop=0, enableConeFriction=False,
deterministicOverlappingPairs=True`, maximal-coordinate bodies, `contactProcessingThreshold=0`).
Where we differ from Kubric, the setting is named in `MoviSettings` and docs/make-dataset.md.

Each object collides as the compound of its asset's convex parts, scaled. The body's origin is
the asset's centre of mass; its inertia is the mesh's own (principal moments, set through
PyBullet's inertial frame), not PyBullet's bounding-box estimate.

Randomness: trajectory `index` of a run with `seed` draws everything from
`numpy.random.SeedSequence([seed, index, attempt])`, so any shard of the indices reproduces
exactly the trajectories of the whole run. A simulated scene that fails a filter (objects
tunnelling through the floor, deep interpenetration, explosion, or no room to place the
objects) is dropped and counted, and the index is retried with the next attempt.
"""

from __future__ import annotations

import collections
import dataclasses
import json
import logging
import time
from pathlib import Path

import numpy as np

from fignetctl.core.obj import write_convex_parts_obj
from fignetctl.core.shapes import configure_kubric_physics
from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile
from fignetctl.core.transforms import (
    lowest_vertex_heights,
    matrix_to_quat,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    quat_wxyz_to_xyzw,
    quat_xyzw_to_wxyz,
    random_quaternions,
)
from fignetctl.errors import FignetError

log = logging.getLogger(__name__)

DROP_REASONS = ("placement", "explosion", "tunnel", "penetration")
FLOOR_NAME = "floor"


# ----------------------------------------------------------------------------- settings


@dataclasses.dataclass(frozen=True)
class Material:
    """Physical properties of a MOVi material.

    density is in Kubric's units: mass [kg] = density × volume [m³] (Kubric multiplies the
    asset's unit-density mass by 2.7 for metal, 1.1 for rubber), so it reads as g/cm³ of a
    world measured in decimetres; only mass ratios matter for the motion.
    """

    name: str
    friction: float
    restitution: float
    density: float


METAL = Material("metal", friction=0.4, restitution=0.3, density=2.7)
RUBBER = Material("rubber", friction=0.8, restitution=0.7, density=1.1)
MOVI_C_MATERIAL = Material("default", friction=0.5, restitution=0.5, density=1.0)


@dataclasses.dataclass(frozen=True)
class MoviSettings:
    """Settings of one MOVi-style dataset; written as json into every output file."""

    preset: str = "movi-b"
    """Name of the preset these settings started from."""
    physics_hz: int = 240
    """PyBullet steps per second (Kubric: 240)."""
    fps: int = 30
    """Recorded frames per second; must divide physics_hz (Kubric renders 12)."""
    duration: float = 4.0
    """Seconds simulated; a trajectory holds round(duration × fps) + 1 frames."""
    gravity: tuple = (0.0, 0.0, -10.0)
    """m/s² (Kubric: (0, 0, -10))."""
    num_objects: tuple = (3, 10)
    """Inclusive range of the number of tossed objects per scene."""
    spawn_region: tuple = ((-5.0, -5.0, 1.0), (5.0, 5.0, 5.0))
    """Corners (m) of the box the objects' centres of mass are drawn from."""
    velocity_range: tuple = ((-4.0, -4.0, 0.0), (4.0, 4.0, 0.0))
    """Corners (m/s) of the random part of the toss; (x, y, 0) is subtracted from it."""
    scale_range: tuple = (0.7, 1.4)
    """Range of the uniform scale factor (or of the largest side, see scale_largest_side)."""
    scale_largest_side: bool = False
    """True: the drawn number is the object's largest side in metres (MOVi-C)."""
    materials: tuple = (METAL, RUBBER)
    """Materials drawn uniformly per object."""
    floor_friction: float = 0.3
    """Floor friction (Kubric: 0.3)."""
    floor_restitution: float = 0.5
    """Floor restitution (Kubric: 0.5)."""
    floor_half_extents: tuple = (40.0, 40.0, 0.1)
    """Half sides (m) of the static floor box; its top face is z = 0."""
    max_placement_trials: int = 100
    """Poses tried per object before the scene counts as dropped for 'placement' (Kubric: 100)."""
    max_attempts: int = 10
    """Scenes tried per trajectory index before the index is given up."""
    tunnel_depth: float = 0.05
    """Drop a scene if an object's mesh stays more than this (m) below the floor top..."""
    max_penetration: float = 0.05
    """...or two objects' collision shapes stay overlapped deeper than this (m)..."""
    sustained_time: float = 0.1
    """...for this long (s). An impact at v m/s overlaps by up to v / physics_hz for a few
    steps (measured at 240 Hz: up to 8 cm, for at most 9 steps) before PyBullet pushes out."""
    hard_depth: float = 0.2
    """Drop a scene at once if any mesh dips this far (m) below the floor top (through the
    0.2 m floor box) or two objects overlap this deeply, or an object's centre is below z = 0."""
    max_speed: float = 50.0
    """Drop a scene if any object moves faster (m/s): an explosion."""
    max_angular_speed: float = 200.0
    """Drop a scene if any object spins faster (rad/s): an explosion."""
    world_bound: float = 100.0
    """Drop a scene if any object leaves the box ±world_bound (m)."""

    @property
    def dt(self) -> float:
        """Seconds between recorded frames."""
        return 1.0 / self.fps

    @property
    def steps_per_frame(self) -> int:
        return self.physics_hz // self.fps

    @property
    def num_frames(self) -> int:
        return int(round(self.duration * self.fps)) + 1

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)


def config_from_json(text: str) -> MoviSettings:
    """The MoviSettings that `MoviSettings.to_json` wrote (a make-dataset file's `config` attribute).

    Raises FignetError for text that is not such json or names settings this version lacks.
    """
    try:
        settings = json.loads(text)
        if not isinstance(settings, dict):
            raise ValueError("it is not a json object")
        materials = settings.pop("materials", None)
        settings = {key: _tuples(value) for key, value in settings.items()}
        if materials is not None:
            settings["materials"] = tuple(Material(**fields) for fields in materials)
        return MoviSettings(**settings)
    except (AttributeError, TypeError, ValueError) as error:
        raise FignetError(f"the generator config is not one this version reads: {error}") from None


def _tuples(value):
    """json lists back to (nested) tuples, as MoviSettings holds them."""
    return tuple(_tuples(item) for item in value) if isinstance(value, list) else value


PRESETS = {
    "movi-b": MoviSettings(),
    "movi-c": MoviSettings(
        preset="movi-c",
        scale_range=(0.75, 3.0),
        scale_largest_side=True,
        materials=(MOVI_C_MATERIAL,),
    ),
}


def movi_config(preset: str, **overrides) -> MoviSettings:
    """The preset's settings with `overrides` (None values are ignored), checked.

    Raises FignetError for an unknown preset, an fps that does not divide the physics
    rate, or a duration that is not positive.
    """
    if preset not in PRESETS:
        raise FignetError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    overrides = {key: value for key, value in overrides.items() if value is not None}
    config = dataclasses.replace(PRESETS[preset], **overrides)
    if config.fps <= 0 or config.physics_hz % config.fps:
        rates = [str(f) for f in range(1, config.physics_hz + 1) if config.physics_hz % f == 0]
        raise FignetError(
            f"fps {config.fps} does not divide the physics rate {config.physics_hz} Hz; "
            f"choose one of {', '.join(rates)}"
        )
    if not config.duration > 0:
        raise FignetError(f"duration must be a positive number of seconds, got {config.duration}")
    return config


# ----------------------------------------------------------------------------- assets


@dataclasses.dataclass(frozen=True)
class Shape:
    """The fields of a ShapeAsset this module uses, as plain arrays (they pickle into workers).

    vertices : (V, 3) float32, object frame, origin at the centre of mass, unscaled
    faces : (F, 3) int32
    convex_parts : tuple of (V_i, 3) float32, what PyBullet collides with
    bounds : (2, 3) float64, the mesh's axis-aligned bounding box in the object frame
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    convex_parts: tuple
    bounds: np.ndarray

    @property
    def largest_side(self) -> float:
        return float((self.bounds[1] - self.bounds[0]).max())


def plain_shapes(assets) -> tuple:
    """Shapes of ShapeAsset-like objects (name, vertices, faces, convex_parts), checked."""
    names = [str(asset.name) for asset in assets]
    if not names:
        raise FignetError("no shapes to simulate")
    if FLOOR_NAME in names or len(set(names)) != len(names):
        raise FignetError(f"shape names must be unique and not {FLOOR_NAME!r}: {sorted(names)}")
    shapes = []
    for name, asset in zip(names, assets):
        vertices = np.asarray(asset.vertices, np.float32)
        parts = tuple(np.asarray(part, np.float32) for part in asset.convex_parts)
        bounds = np.stack([vertices.min(axis=0), vertices.max(axis=0)]).astype(np.float64)
        shapes.append(Shape(name, vertices, np.asarray(asset.faces, np.int32), parts, bounds))
    return tuple(shapes)


@dataclasses.dataclass(frozen=True)
class PreparedAsset:
    """A shape ready to simulate, with unit-density, unscaled mass properties.

    shape : the Shape (its mesh is what the file stores)
    hull_vertices : (H, 3) float64, vertices of the mesh's convex hull (for floor checks)
    collision_file : OBJ file holding the convex parts, one `o` group each
    volume : m³ of the unscaled shape
    principal_moments : (3,) float64, inertia at density 1 about the origin, principal axes
    principal_quaternion : (4,) float64 w x y z, principal frame -> object frame
    """

    shape: Shape
    hull_vertices: np.ndarray
    collision_file: str
    volume: float
    principal_moments: np.ndarray
    principal_quaternion: np.ndarray

    @property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia tensor at density 1 in the object frame."""
        axes = quat_to_matrix(self.principal_quaternion)
        return axes @ np.diag(self.principal_moments) @ axes.T


def prepare_asset(shape: Shape, folder) -> PreparedAsset:
    """Mass properties of `shape`, and its convex parts written to an OBJ in `folder`."""
    import hashlib

    parts = [np.asarray(part, np.float64) for part in shape.convex_parts]
    # PyBullet caches OBJ files by path for the life of the process: name them by content.
    digest = hashlib.sha256(b"".join(part.tobytes() for part in parts)).hexdigest()
    collision_file = Path(folder) / f"{digest[:24]}.obj"
    write_convex_parts_obj(parts, collision_file)
    volume, inertia = mass_properties(shape.vertices, shape.faces, parts)
    moments, quaternion = principal_frame(inertia)
    return PreparedAsset(
        shape=shape,
        hull_vertices=hull_vertices(shape.vertices),
        collision_file=str(collision_file),
        volume=volume,
        principal_moments=moments,
        principal_quaternion=quaternion,
    )


def hull_vertices(vertices) -> np.ndarray:
    """(H, 3) float64: the vertices on the convex hull (the lowest point is always one)."""
    from scipy.spatial import ConvexHull, QhullError

    vertices = np.asarray(vertices, np.float64)
    try:
        return vertices[ConvexHull(vertices).vertices]
    except (QhullError, ValueError):  # flat or tiny meshes: keep every vertex
        return vertices


def mass_properties(vertices, faces, convex_parts) -> tuple:
    """Volume and (3, 3) inertia tensor about the origin, at density 1, unscaled.

    vertices : (V, 3), faces : (F, 3): the mesh, used when it encloses a volume
    convex_parts : list of (V_i, 3): summed as convex hulls otherwise (overlaps count twice)
    """
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces)
    pieces = [mesh] if mesh.is_volume else [trimesh.convex.convex_hull(p) for p in convex_parts]
    volume = float(sum(piece.volume for piece in pieces))
    if not volume > 0:
        raise FignetError("a shape encloses no volume: its mesh and convex parts are flat")
    inertia = sum(_inertia_about_origin(piece) for piece in pieces)
    return volume, np.asarray(inertia, np.float64)


def _inertia_about_origin(mesh) -> np.ndarray:
    """Parallel-axis shift of trimesh's inertia about the centre of mass (density 1)."""
    centre = np.asarray(mesh.center_mass, np.float64)
    shift = mesh.volume * (centre @ centre * np.eye(3) - np.outer(centre, centre))
    return np.asarray(mesh.moment_inertia, np.float64) + shift


def principal_frame(inertia) -> tuple:
    """Principal moments (3,) and the quaternion (4,) w x y z of the principal axes.

    The quaternion's rotation maps principal-frame coordinates to object coordinates
    (its matrix has the principal axes as columns, right-handed).
    """
    moments, axes = np.linalg.eigh(np.asarray(inertia, np.float64))
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    return np.maximum(moments, 0.0), matrix_to_quat(axes)


# ----------------------------------------------------------------------------- seeds, shards


def trajectory_rng(seed: int, index: int, attempt: int = 0) -> np.random.Generator:
    """The random stream of one scene: a function of (seed, global index, attempt) only."""
    entropy = [int(seed) & 0xFFFFFFFFFFFFFFFF, int(index), int(attempt)]
    return np.random.default_rng(np.random.SeedSequence(entropy))


def shard_indices(num_trajectories: int, shard_index: int = 0, shard_count: int = 1) -> range:
    """Global trajectory indices of one shard: k with k mod shard_count == shard_index."""
    if not 0 <= shard_index < shard_count:
        raise FignetError(f"shard {shard_index}/{shard_count}: need 0 <= i < n")
    return range(shard_index, num_trajectories, shard_count)


def trajectory_id(index: int, num_trajectories: int) -> str:
    """Zero-padded global index ("00042"), the same width in every shard of a run."""
    return f"{index:0{max(5, len(str(max(num_trajectories - 1, 0))))}d}"


# ----------------------------------------------------------------------------- scene sampling


@dataclasses.dataclass(frozen=True)
class ObjectSpec:
    """One tossed object: which asset, its uniform scale and its material."""

    asset: int
    scale: float
    material: Material


def sample_objects(rng, largest_sides, config: MoviSettings) -> list:
    """Draw the number of objects, then each one's asset, scale and material.

    largest_sides : (A,) the largest side of each asset (for scale_largest_side)
    """
    low, high = config.num_objects
    specs = []
    for _ in range(int(rng.integers(low, high + 1))):
        asset = int(rng.integers(len(largest_sides)))
        size = float(rng.uniform(*config.scale_range))
        scale = size / largest_sides[asset] if config.scale_largest_side else size
        material = config.materials[int(rng.integers(len(config.materials)))]
        specs.append(ObjectSpec(asset, scale, material))
    return specs


def rotated_box(bounds, quaternion) -> tuple:
    """World-axis extent (low (3,), high (3,)) of a box `bounds` (2, 3) turned by `quaternion`
    (w x y z) about the origin: Kubric's `aabbox` of a rotated object at the origin."""
    corners = np.array(
        [[bounds[i, 0], bounds[j, 1], bounds[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    )
    turned = corners @ quat_to_matrix(quaternion).T
    return turned.min(axis=0), turned.max(axis=0)


def toss_velocity(rng, position, config: MoviSettings) -> np.ndarray:
    """(3,) m/s: U(velocity_range) - (x, y, 0), biased toward the centre as in Kubric."""
    low, high = (np.asarray(corner, np.float64) for corner in config.velocity_range)
    return rng.uniform(low, high) - np.array([position[0], position[1], 0.0])


# ----------------------------------------------------------------------------- simulation


@dataclasses.dataclass
class SimulationRecord:
    """States of O bodies (the floor first) at T recorded frames.

    positions : (T, O, 3) centre of mass, quaternions : (T, O, 4) w x y z object-to-world
    velocities, angular_velocities : (T, O, 3) world frame, m/s and rad/s
    min_pair_distance : (T,) the deepest contact distance between two tossed objects (m,
        negative when they overlap; +inf without contacts)
    """

    positions: np.ndarray
    quaternions: np.ndarray
    velocities: np.ndarray
    angular_velocities: np.ndarray
    min_pair_distance: np.ndarray


@dataclasses.dataclass
class TrajectoryResult:
    """What became of one global trajectory index.

    trajectory is None when every attempt was dropped; drops counts the dropped attempts
    by reason (see DROP_REASONS).
    """

    index: int
    attempt: int | None
    trajectory: Trajectory | None
    drops: dict
    seconds: float


class MoviSimulator:
    """One PyBullet DIRECT client that simulates scenes one at a time.

    shapes : Shapes (see plain_shapes); each is prepared (mass properties, an OBJ of its
        convex parts in `folder`) when a scene first uses it.
    The world is reset before each scene, so a scene depends only on its random stream.
    """

    def __init__(self, shapes, config: MoviSettings, folder):
        import pybullet

        self.pybullet = pybullet
        self.shapes = tuple(shapes)
        self.largest_sides = np.array([shape.largest_side for shape in self.shapes])
        self.config = config
        self.folder = Path(folder)
        self.prepared = {}
        self.client = pybullet.connect(pybullet.DIRECT)

    def asset(self, index: int) -> PreparedAsset:
        if index not in self.prepared:
            self.prepared[index] = prepare_asset(self.shapes[index], self.folder)
        return self.prepared[index]

    def close(self) -> None:
        if self.client is not None:
            self.pybullet.disconnect(physicsClientId=self.client)
            self.client = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def build_scene(self, specs) -> list:
        """A fresh world with the floor and one body per ObjectSpec, parked out of the way
        (place them with set_object_states). Returns the body ids, the floor first."""
        self._reset_world()
        return [self._add_floor()] + [self._add_object(spec) for spec in specs]

    def set_object_states(
        self, bodies, specs, positions, quaternions, velocities, angular_velocities
    ) -> None:
        """Put each spec's body (bodies[1:], the floor stays) in an object-frame state.

        positions : (N, 3) centre of mass, quaternions : (N, 4) w x y z object-to-world,
        velocities, angular_velocities : (N, 3) world frame; N = len(specs)
        """
        p, client = self.pybullet, self.client
        principal = np.stack([self.asset(spec.asset).principal_quaternion for spec in specs])
        inertial = quat_wxyz_to_xyzw(inertial_quaternions(quat_normalize(quaternions), principal))
        for body, position, orientation, velocity, angular in zip(
            bodies[1:], positions, inertial, velocities, angular_velocities
        ):
            p.resetBasePositionAndOrientation(body, list(position), list(orientation), physicsClientId=client)
            p.resetBaseVelocity(body, list(velocity), list(angular), physicsClientId=client)

    def object_states(self, bodies, specs) -> tuple:
        """The state of each spec's body (bodies[1:]) in the object frame, float64:
        positions (N, 3), quaternions (N, 4) w x y z, velocities (N, 3), angular velocities (N, 3)."""
        states = np.array([self._state(body) for body in bodies[1:]], np.float64).reshape(-1, 13)
        principal = np.stack([self.asset(spec.asset).principal_quaternion for spec in specs])
        quaternions = object_quaternions(quat_xyzw_to_wxyz(states[:, 3:7]), principal)
        return states[:, :3], quaternions, states[:, 7:10], states[:, 10:13]

    def step_frame(self) -> None:
        """Advance the world by one recorded frame: steps_per_frame physics steps."""
        for _ in range(self.config.steps_per_frame):
            self.pybullet.stepSimulation(physicsClientId=self.client)

    def simulate(self, seed: int, index: int) -> TrajectoryResult:
        """Simulate trajectory `index` of a run with `seed`, retrying dropped scenes."""
        start, drops = time.perf_counter(), collections.Counter()
        for attempt in range(self.config.max_attempts):
            trajectory, reason = self.simulate_scene(trajectory_rng(seed, index, attempt))
            if reason is None:
                trajectory.extras["attempt"] = np.int32(attempt)
                return TrajectoryResult(index, attempt, trajectory, dict(drops), time.perf_counter() - start)
            log.debug("trajectory %d attempt %d dropped: %s", index, attempt, reason)
            drops[reason] += 1
        return TrajectoryResult(index, None, None, dict(drops), time.perf_counter() - start)

    def simulate_scene(self, rng) -> tuple:
        """(Trajectory, None) for a kept scene, (None, reason) for a dropped one."""
        self._reset_world()
        specs = sample_objects(rng, self.largest_sides, self.config)
        bodies = [self._add_floor()]
        for spec in specs:
            body = self._add_object(spec)
            if not self._place(body, spec, rng, bodies):
                return None, "placement"
            bodies.append(body)
            position, _ = self.pybullet.getBasePositionAndOrientation(body, physicsClientId=self.client)
            velocity = toss_velocity(rng, position, self.config)
            self.pybullet.resetBaseVelocity(body, velocity.tolist(), [0, 0, 0], physicsClientId=self.client)
        record = self._run(bodies, specs)
        reason = drop_reason(record, self._scales(specs), self._hulls(specs), self.config)
        return (None, reason) if reason else (self._trajectory(specs, record), None)

    # -- world
    def _reset_world(self) -> None:
        p, client = self.pybullet, self.client
        p.resetSimulation(physicsClientId=client)
        configure_kubric_physics(client, self.config.gravity, self.config.physics_hz)

    def _add_floor(self) -> int:
        p, config = self.pybullet, self.config
        half_extents = list(config.floor_half_extents)
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half_extents, physicsClientId=self.client)
        body = p.createMultiBody(
            0.0,
            shape,
            basePosition=_floor_position(config),
            useMaximalCoordinates=True,
            physicsClientId=self.client,
        )
        p.changeDynamics(
            body,
            -1,
            lateralFriction=config.floor_friction,
            restitution=config.floor_restitution,
            contactProcessingThreshold=0.0,
            physicsClientId=self.client,
        )
        return body

    def _add_object(self, spec: ObjectSpec) -> int:
        """A body of the scaled convex parts; its inertial frame is the principal frame."""
        p, asset = self.pybullet, self.asset(spec.asset)
        mass, moments = object_mass_properties(asset, spec)
        shape = p.createCollisionShape(
            p.GEOM_MESH,
            fileName=asset.collision_file,
            meshScale=[spec.scale] * 3,
            physicsClientId=self.client,
        )
        body = p.createMultiBody(
            mass,
            shape,
            basePosition=[0.0, 0.0, -1000.0],
            baseInertialFramePosition=[0.0, 0.0, 0.0],
            baseInertialFrameOrientation=quat_wxyz_to_xyzw(asset.principal_quaternion).tolist(),
            useMaximalCoordinates=True,
            physicsClientId=self.client,
        )
        # PyBullet 3.2.7 zeroes the mass when localInertiaDiagonal comes without it.
        p.changeDynamics(
            body,
            -1,
            mass=mass,
            localInertiaDiagonal=moments.tolist(),
            lateralFriction=spec.material.friction,
            restitution=spec.material.restitution,
            contactProcessingThreshold=0.0,
            physicsClientId=self.client,
        )
        return body

    def _place(self, body: int, spec: ObjectSpec, rng, others: list) -> bool:
        """Kubric's move_until_no_overlap: random poses until none touches `others`.

        As in Kubric, a random rotation, then a position that keeps the rotated bounding
        box inside the spawn region.
        """
        p, asset = self.pybullet, self.asset(spec.asset)
        low, high = (np.asarray(corner, np.float64) for corner in self.config.spawn_region)
        for _ in range(self.config.max_placement_trials):
            rotation = random_quaternions(rng, 1)[0]
            box_low, box_high = rotated_box(asset.shape.bounds * spec.scale, rotation)
            # A box larger than the region (a big cube on its corner) gets low > high: Kubric's
            # RandomState.uniform then draws between the two, and so do we.
            ends = np.stack([low - box_low, high - box_high])
            position = rng.uniform(ends.min(axis=0), ends.max(axis=0))
            # PyBullet poses the inertial (principal) frame: object rotation ⊗ principal rotation.
            inertial = quat_multiply(rotation, asset.principal_quaternion)
            p.resetBasePositionAndOrientation(
                body, position.tolist(), quat_wxyz_to_xyzw(inertial).tolist(), physicsClientId=self.client
            )
            if not any(p.getClosestPoints(body, other, 0.0, physicsClientId=self.client) for other in others):
                return True
        return False

    # -- run and record
    def _run(self, bodies: list, specs: list) -> SimulationRecord:
        """Record every steps_per_frame physics steps, from the initial state on."""
        frames = self.config.num_frames
        states = np.zeros((frames, len(bodies), 13))
        min_pair_distance = np.full(frames, np.inf)
        for frame in range(frames):
            if frame:
                self.step_frame()
            states[frame] = [self._state(body) for body in bodies]
            min_pair_distance[frame] = self._min_pair_distance(floor=bodies[0])
        principal = [np.array([1.0, 0, 0, 0])] + [self.asset(s.asset).principal_quaternion for s in specs]
        quaternions = object_quaternions(quat_xyzw_to_wxyz(states[..., 3:7]), np.stack(principal))
        return SimulationRecord(
            positions=states[..., :3],
            quaternions=quaternions,
            velocities=states[..., 7:10],
            angular_velocities=states[..., 10:13],
            min_pair_distance=min_pair_distance,
        )

    def _state(self, body: int) -> list:
        """13 numbers: position, inertial-frame quaternion x y z w, velocity, angular velocity."""
        position, orientation = self.pybullet.getBasePositionAndOrientation(body, physicsClientId=self.client)
        velocity, angular = self.pybullet.getBaseVelocity(body, physicsClientId=self.client)
        return [*position, *orientation, *velocity, *angular]

    def _min_pair_distance(self, floor: int) -> float:
        """The most negative contact distance between two tossed objects (inf if none)."""
        distances = [
            contact[8]
            for contact in self.pybullet.getContactPoints(physicsClientId=self.client)
            if floor not in (contact[1], contact[2])
        ]
        return min(distances, default=np.inf)

    # -- output
    def _scales(self, specs) -> np.ndarray:
        return np.array([1.0] + [spec.scale for spec in specs])

    def _hulls(self, specs) -> list:
        return [None] + [self.asset(spec.asset).hull_vertices for spec in specs]

    def _trajectory(self, specs: list, record: SimulationRecord) -> Trajectory:
        """The kept scene in the trajectory format, floor first, with physical extras."""
        config, assets = self.config, [self.asset(s.asset) for s in specs]
        properties = [object_mass_properties(asset, s) for asset, s in zip(assets, specs)]
        inertia = [np.zeros((3, 3))] + [
            s.material.density * s.scale**5 * asset.inertia for asset, s in zip(assets, specs)
        ]
        return Trajectory(
            mesh_names=np.array([FLOOR_NAME] + [asset.shape.name for asset in assets], dtype=object),
            scales=self._scales(specs).astype(np.float32),
            positions=record.positions.astype(np.float32),
            quaternions=record.quaternions.astype(np.float32),
            static=np.array([True] + [False] * len(specs)),
            mass=np.array([0.0] + [mass for mass, _ in properties], np.float32),
            friction=np.array([config.floor_friction] + [s.material.friction for s in specs], np.float32),
            restitution=np.array(
                [config.floor_restitution] + [s.material.restitution for s in specs], np.float32
            ),
            velocities=record.velocities.astype(np.float32),
            angular_velocities=record.angular_velocities.astype(np.float32),
            extras=_physical_extras(record, np.stack(inertia)),
        )


def inertial_quaternions(rotations, principal) -> np.ndarray:
    """PyBullet's base orientation of objects turned by `rotations`: rotation ⊗ principal.

    rotations : (..., 4) w x y z object-to-world; principal : (..., 4) w x y z, broadcast
    returns : (..., 4) float64 w x y z
    """
    return quat_multiply(rotations, principal)


def object_quaternions(base_orientations, principal) -> np.ndarray:
    """The object rotations of PyBullet's base orientations: base ⊗ principal⁻¹, unit.

    base_orientations : (..., 4) w x y z; principal : (..., 4) w x y z, broadcast
    returns : (..., 4) float64 w x y z
    """
    return quat_normalize(quat_multiply(base_orientations, quat_conjugate(principal)))


def object_mass_properties(asset: PreparedAsset, spec: ObjectSpec) -> tuple:
    """Mass (kg) and principal moments (3,) kg m² of the scaled asset in its material."""
    density, scale = spec.material.density, spec.scale
    return density * scale**3 * asset.volume, density * scale**5 * asset.principal_moments


def _physical_extras(record: SimulationRecord, inertia: np.ndarray) -> dict:
    """Extra per-trajectory datasets: final speeds and inertia tensors."""
    return {
        "final_speed": np.linalg.norm(record.velocities[-1], axis=-1).astype(np.float32),
        "final_angular_speed": np.linalg.norm(record.angular_velocities[-1], axis=-1).astype(np.float32),
        "inertia": inertia.astype(np.float32),
    }


def _floor_position(config: MoviSettings) -> list:
    return [0.0, 0.0, -float(config.floor_half_extents[2])]


# ----------------------------------------------------------------------------- filters


def drop_reason(record: SimulationRecord, scales, hulls, config: MoviSettings) -> str | None:
    """Why a simulated scene must be dropped ('explosion', 'tunnel', 'penetration'), or None.

    scales : (O,) per body; hulls : per body, (H, 3) hull vertices or None for the floor
    (object 0, which is never checked).
    """
    if _exploded(record, config):
        return "explosion"
    lowest = lowest_vertex_heights(record.positions[:, 1:], record.quaternions[:, 1:], scales[1:], hulls[1:])
    depth = -lowest.min(axis=1)  # (T,) the deepest dip below the floor top per frame
    if record.positions[:, 1:, 2].min() < 0.0 or _too_deep(depth, config.tunnel_depth, config):
        return "tunnel"
    if _too_deep(-record.min_pair_distance, config.max_penetration, config):
        return "penetration"
    return None


def _too_deep(depth, limit: float, config: MoviSettings) -> bool:
    """depth : (T,) m per recorded frame. Beyond hard_depth once, or beyond `limit` in
    consecutive frames spanning at least sustained_time."""
    if depth.max() > config.hard_depth:
        return True
    return (_longest_run(depth > limit) - 1) * config.dt >= config.sustained_time


def _longest_run(mask) -> int:
    """Length of the longest run of True in a 1-D boolean array."""
    padded = np.concatenate([[0], np.asarray(mask, np.int8), [0]])
    edges = np.flatnonzero(np.diff(padded))
    return int((edges[1::2] - edges[::2]).max(initial=0))


def _exploded(record: SimulationRecord, config: MoviSettings) -> bool:
    arrays = (record.positions, record.quaternions, record.velocities, record.angular_velocities)
    if not all(np.all(np.isfinite(array)) for array in arrays):
        return True
    speed = np.linalg.norm(record.velocities, axis=-1).max()
    angular_speed = np.linalg.norm(record.angular_velocities, axis=-1).max()
    far = np.abs(record.positions).max()
    return speed > config.max_speed or angular_speed > config.max_angular_speed or far > config.world_bound


# ----------------------------------------------------------------------------- parallel runs


_WORKER: MoviSimulator | None = None


def _start_worker(shapes, config, folder) -> None:
    global _WORKER
    _WORKER = MoviSimulator(shapes, config, folder)


def _work(task) -> TrajectoryResult:
    seed, index = task
    return _WORKER.simulate(seed, index)


def generate(assets, config: MoviSettings, seed: int, indices, jobs: int = 1):
    """Yield a TrajectoryResult per global index, in the order of `indices`.

    assets : ShapeAsset-like objects (name, vertices, faces, convex_parts)
    jobs : worker processes ("spawn"), each with its own PyBullet client (1: this process).
        A script that asks for jobs > 1 must guard its entry point with
        `if __name__ == "__main__":`, as multiprocessing requires.
    """
    import multiprocessing
    import tempfile

    shapes, indices = plain_shapes(assets), list(indices)
    with tempfile.TemporaryDirectory(prefix="fignetctl-movi-") as folder:
        if jobs <= 1 or len(indices) <= 1:
            with MoviSimulator(shapes, config, folder) as simulator:
                yield from (simulator.simulate(seed, index) for index in indices)
            return
        context = multiprocessing.get_context("spawn")
        with context.Pool(min(jobs, len(indices)), _start_worker, (shapes, config, folder)) as pool:
            yield from pool.imap(_work, [(seed, index) for index in indices])


# ----------------------------------------------------------------------------- the file


DATASET_COUNTS = ("requested", "kept", "given_up", "attempts", "dropped")
"""The `dataset_stats` that follow from the settings alone (the others are timings)."""


def dataset_stats(results: list, seconds: float, jobs: int) -> dict:
    """Counts of kept, dropped (by reason) and given-up trajectories, and the throughput.

    seconds : wall time of the run; simulation_seconds adds up each trajectory's own time
    (over all workers), so simulation_seconds / seconds is the parallel speed-up.
    """
    drops = collections.Counter()
    for result in results:
        drops.update(result.drops)
    kept = sum(result.trajectory is not None for result in results)
    return {
        "requested": len(results),
        "kept": kept,
        "given_up": len(results) - kept,
        "attempts": kept + sum(drops.values()),
        "dropped": {reason: int(drops[reason]) for reason in DROP_REASONS},
        "seconds": round(float(seconds), 3),
        "simulation_seconds": round(float(sum(result.seconds for result in results)), 3),
        "jobs": int(jobs),
        "trajectories_per_minute": round(60.0 * kept / max(seconds, 1e-9), 2),
    }


def dataset_file(
    results: list, assets, config: MoviSettings, num_trajectories: int, attrs: dict
) -> TrajectoryFile:
    """The kept trajectories as a TrajectoryFile holding the floor and the shapes they use.

    Raises FignetError when no trajectory was kept.
    """
    kept = [result for result in results if result.trajectory is not None]
    if not kept:
        raise FignetError("no trajectory passed the filters; see the drop counts above")
    used = {str(name) for result in kept for name in result.trajectory.mesh_names}
    meshes = {FLOOR_NAME: floor_mesh(config)}
    for asset in assets:
        if str(asset.name) in used:
            meshes[str(asset.name)] = Mesh(
                np.asarray(asset.vertices, np.float32), np.asarray(asset.faces, np.int32)
            )
    trajectories = {trajectory_id(r.index, num_trajectories): r.trajectory for r in kept}
    return TrajectoryFile(
        dt=config.dt,
        gravity=np.asarray(config.gravity, np.float64),
        meshes=meshes,
        trajectories=trajectories,
        attrs=dict(attrs),
    )


def floor_mesh(config: MoviSettings) -> Mesh:
    """The floor box (8 vertices, 12 outward triangles), centred on its own origin."""
    import trimesh

    box = trimesh.creation.box(extents=2.0 * np.asarray(config.floor_half_extents))
    return Mesh(np.asarray(box.vertices, np.float32), np.asarray(box.faces, np.int32))
