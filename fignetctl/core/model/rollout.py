"""Rollouts: apply the learned simulator step after step, with checks that stop a bad one.

A rollout starts from frames 0 and 1 of a scene (t−1, t) and appends predicted frames, so frame
1 + k is step k, as in a rollout file. Static objects follow their given frames where the scene
has them and stay at their last given pose after. A non-finite pose, or an object farther than
`max_distance` from where it started, stops the rollout with `RolloutError`, which names the
step and the object and carries the frames computed so far.

Sleeping (optional, `SleepSettings`): a dynamic object whose fastest point has moved slower
than `froude · √(g · size)` for `frames` frames in a row falls asleep. An asleep object is
simulated as static at its pose (no nodes unless something comes near, no prediction), and
wakes when an awake dynamic object comes within the collision radius of it (bounding spheres).
When every dynamic object is asleep a step costs nothing. Objects near each other sleep
together: one that is still but near an awake object stays awake (without losing its count
of still frames), so a resting pile falls asleep as soon as all of it is still. The threshold is a Froude number, so
it means the same at every size and under `--sim-scale`: 9 cm/s for a 2 m object, 2 cm/s
for a 10 cm one.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from fignetctl.core.model.penetration import push_out_of_static
from fignetctl.core.transforms import quat_angle_deg
from fignetctl.errors import FignetError

MAX_DISTANCE = 1000.0


class RolloutError(FignetError):
    """A rollout that went wrong; `positions`/`quaternions` hold the frames before the bad one."""

    def __init__(self, message, positions, quaternions):
        super().__init__(message)
        self.positions = positions
        self.quaternions = quaternions
        self.partial_file = None  # filled by apply.rollout_trajectory: the frames so far, as a TrajectoryFile


def given_static_pose(scene, frame):
    """(O, 3), (O, 4): the scene's pose at `frame`, or its last one past the end."""
    frame = min(frame, scene.positions.shape[0] - 1)
    return scene.positions[frame], scene.quaternions[frame]


@dataclasses.dataclass(frozen=True)
class SleepSettings:
    """When a resting object stops being simulated (module docstring)."""

    froude: float = 0.02
    """Speed threshold as a fraction of √(g · size), size the object's largest bounding-sphere diameter."""
    frames: int = 10
    """Frames in a row below the threshold before an object falls asleep."""
    dt: float = 1 / 30
    """Seconds per frame (of the simulated scene)."""
    gravity: float = 9.81
    """|g| in m/s²."""


class Sleepers:
    """Which dynamic objects are asleep, and the scene geometry that simulates them as static."""

    def __init__(self, geometry, settings: SleepSettings, collision_radius: float):
        self.geometry, self.settings, self.collision_radius = geometry, settings, collision_radius
        rest = geometry.rest_vertices
        self.radius = np.array(
            [
                np.linalg.norm(rest[geometry.vertex_object == o], axis=1).max(initial=0.0)
                for o in range(len(geometry.static))
            ]
        )
        self.threshold = (
            settings.froude * np.sqrt(settings.gravity * 2.0 * self.radius) * settings.dt
        )  # per frame
        self.still = np.zeros(len(geometry.static), int)
        self.asleep = np.zeros(len(geometry.static), bool)
        self._geometries = {}

    def update(self, previous_positions, previous_quaternions, positions, quaternions, moving_static):
        """Count still frames (frame t−1 → t), put objects to sleep and wake the ones something
        approaches (an awake dynamic object, or a static one in `moving_static`, bool (O,))."""
        dynamic = ~self.geometry.static
        turn = np.radians(quat_angle_deg(quaternions, previous_quaternions))
        fastest = (
            np.linalg.norm(positions - previous_positions, axis=1) + turn * self.radius
        )  # bound on any point's step
        self.still = np.where(dynamic & (fastest < self.threshold), self.still + 1, 0)
        self.asleep = dynamic & (self.still >= self.settings.frames)
        while True:  # an object near an awake one is awake, and so on along chains of neighbours
            awake = np.flatnonzero((dynamic & ~self.asleep) | moving_static)
            woken = [
                o
                for o in np.flatnonzero(self.asleep)
                if np.any(
                    np.linalg.norm(positions[awake] - positions[o], axis=1)
                    - self.radius[awake]
                    - self.radius[o]
                    < self.collision_radius
                )
            ]
            if not woken:
                break
            self.asleep[woken] = False  # its still count goes on: it sleeps with its neighbours

    def all_asleep(self) -> bool:
        return bool(np.all(self.asleep | self.geometry.static))

    def scene_geometry(self):
        """The geometry with asleep objects static (one per set of sleepers, kept)."""
        if not self.asleep.any():
            return self.geometry
        key = tuple(np.flatnonzero(self.asleep))
        if key not in self._geometries:
            self._geometries[key] = dataclasses.replace(
                self.geometry, static=self.geometry.static | self.asleep
            )
        return self._geometries[key]


@dataclasses.dataclass(frozen=True)
class Guards:
    """What a rollout adds around the network (none by default: the network alone)."""

    sleep: SleepSettings | None = None
    """Let resting objects sleep (module docstring); None: never."""
    free_flight: tuple | None = None
    """gravity · dt² (3,) in metres per step²: objects that touch nothing move in exact free
    flight (LearnedSimulator.predict); None: the network moves every dynamic object."""
    keep_out: bool = False
    """After each step, translate dynamic objects back out of the static meshes (and asleep
    objects) they passed into (penetration.push_out_of_static); a velocity-state model's
    object also loses the part of its velocity along the push."""


def guards_for(dt, gravity, sleep=False, free_flight=False, keep_out=False) -> Guards:
    """The Guards of a scene with frame time dt (s) and gravity (3,) m/s², from three switches."""
    magnitude = float(np.linalg.norm(gravity))
    settings = SleepSettings(dt=float(dt), gravity=magnitude if magnitude > 0 else 9.81) if sleep else None
    acceleration = tuple(float(g) * float(dt) ** 2 for g in gravity) if free_flight else None
    return Guards(settings, acceleration, bool(keep_out))


def rollout(
    simulator,
    scene,
    num_steps,
    on_step=None,
    max_distance=MAX_DISTANCE,
    guards: Guards = Guards(),
    with_velocities=False,
):
    """Predict `num_steps` frames after frames 0 and 1 of `scene`, with the `guards`.

    with_velocities : also return the velocities a velocity-state model carries
    returns positions (2 + K, O, 3), quaternions (2 + K, O, 4) float64, and with
        `with_velocities` velocities and angular velocities (2 + K, O, 3) in m/s and rad/s
        (frames 0 and 1 the scene's; None for a positions-state model)
    """
    positions = [scene.positions[0], scene.positions[1]]
    quaternions = [scene.quaternions[0], scene.quaternions[1]]
    carries = simulator.config.uses_velocities
    velocities = [scene.velocities[0], scene.velocities[1]] if carries else None
    angular = [scene.angular_velocities[0], scene.angular_velocities[1]] if carries else None
    free_flight = None if guards.free_flight is None else np.asarray(guards.free_flight, np.float64)
    sleepers = (
        None
        if guards.sleep is None
        else Sleepers(scene.geometry, guards.sleep, simulator.config.graph.collision_radius)
    )
    for step in range(num_steps):
        next_static = given_static_pose(scene, step + 2)
        if sleepers is not None:
            moving_static = scene.geometry.static & (
                np.any(next_static[0] != positions[-1], axis=1)
                | np.any(next_static[1] != quaternions[-1], axis=1)
            )
            sleepers.update(positions[-2], quaternions[-2], positions[-1], quaternions[-1], moving_static)
            next_static = (
                np.where(sleepers.asleep[:, None], positions[-1], next_static[0]),
                np.where(sleepers.asleep[:, None], quaternions[-1], next_static[1]),
            )
        if sleepers is not None and sleepers.all_asleep():
            new_position, new_quaternion = next_static
            new_velocity = new_angular = np.zeros_like(new_position) if carries else None
        else:
            geometry = scene.geometry if sleepers is None else sleepers.scene_geometry()
            history_positions = np.stack([positions[-2], positions[-1], next_static[0]])
            history_quaternions = np.stack([quaternions[-2], quaternions[-1], next_static[1]])
            state = (velocities[-1], angular[-1]) if carries else None
            new_position, new_quaternion, new_velocity, new_angular = simulator.predict(
                geometry, history_positions, history_quaternions, free_flight=free_flight, velocities=state
            )
            if guards.keep_out:
                predicted = new_position
                new_position, _ = push_out_of_static(
                    geometry, positions[-1], quaternions[-1], new_position, new_quaternion
                )
                if carries:
                    new_velocity = without_velocity_into(new_velocity, new_position - predicted)
        check_step(step, new_position, new_quaternion, positions, quaternions, max_distance)
        positions.append(new_position)
        quaternions.append(new_quaternion)
        if carries:
            velocities.append(new_velocity)
            angular.append(new_angular)
        if on_step is not None:
            on_step(step)
    result = np.stack(positions), np.stack(quaternions)
    if not with_velocities:
        return result
    return (*result, None, None) if not carries else (*result, np.stack(velocities), np.stack(angular))


def without_velocity_into(velocities, pushes):
    """(O, 3) velocities less their component against each object's push (O, 3) out of a static
    mesh (an inelastic impact along the push); objects not pushed keep theirs."""
    length = np.linalg.norm(pushes, axis=1, keepdims=True)
    direction = np.divide(pushes, length, out=np.zeros_like(pushes), where=length > 0)
    into = np.minimum(np.sum(velocities * direction, axis=1, keepdims=True), 0.0)
    return velocities - into * direction


def check_step(step, new_position, new_quaternion, positions, quaternions, max_distance):
    """Raise RolloutError (with the frames so far) for a non-finite or runaway object."""
    finite = np.isfinite(new_position).all(axis=1) & np.isfinite(new_quaternion).all(axis=1)
    distance = np.linalg.norm(np.nan_to_num(new_position, nan=np.inf) - positions[0], axis=1)
    bad = np.flatnonzero(~finite | (distance > max_distance))
    if bad.size:
        obj = int(bad[0])
        what = "a non-finite pose" if not finite[obj] else f"moved {distance[obj]:.3g} m from its start"
        raise RolloutError(
            f"rollout stopped at step {step}: object {obj} has {what}; "
            f"the {len(positions)} frames before it were kept",
            np.stack(positions),
            np.stack(quaternions),
        )
