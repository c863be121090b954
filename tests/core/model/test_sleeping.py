"""Sleeping: resting objects stop being simulated and wake when something comes near."""

import dataclasses

import numpy as np

from fignetctl.core.model.rollout import Guards, SleepSettings, rollout
from fignetctl.core.model.scene_data import Scene
from fignetctl.core.model.scene_graph import scene_geometry
from fignetctl.core.model.simulator import SimulatorConfig
from fignetctl.core.transforms import IDENTITY_QUATERNION


class DriftingSimulator:
    """Constant velocity for dynamic objects, plus a spurious acceleration of `drift` m/step²
    along x (what a learned model does to a resting object); an object that a moving one comes within 0.5 m of
    is pushed along y. Records the static flags of every geometry it is given."""

    def __init__(self, drift=2e-5):
        self.config = SimulatorConfig()
        self.drift = drift
        self.static_seen = []

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        return (*self.step(geometry, positions, quaternions, free_flight), None, None)

    def step(self, geometry, positions, quaternions, free_flight=None):
        static = geometry.static
        self.static_seen.append(static.copy())
        new = positions[2].copy()
        dynamic = ~static
        new[dynamic] = 2 * positions[1, dynamic] - positions[0, dynamic] + [self.drift, 0, 0]
        for o in np.flatnonzero(dynamic):
            others = np.flatnonzero(dynamic & (np.arange(len(static)) != o))
            if np.any(np.linalg.norm(positions[1, others] - positions[1, o], axis=1) < 1.5):
                new[o, 1] += 0.01
        return new, quaternions[2].copy()


def cube_scene(starts, velocities, dt=1 / 30):
    """Unit cubes (vertices ±0.5) at `starts` (O, 3) with `velocities` (O, 3) m/s, on a static floor."""
    cube = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], float)
    faces = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ]
    )
    floor = (
        np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float),
        np.array([[0, 1, 2], [0, 2, 3]]),
    )
    count = len(starts)
    meshes = [floor] + [(cube, faces)] * count
    static = np.array([True] + [False] * count)
    geometry = scene_geometry(meshes, np.ones(count + 1), static, np.ones((count + 1, 3)))
    now = np.concatenate([[[0, 0, 0]], np.asarray(starts, float)])
    before = now - np.concatenate([[[0, 0, 0]], np.asarray(velocities, float)]) * dt
    positions = np.stack([before, now])
    quaternions = np.broadcast_to(IDENTITY_QUATERNION, (2, count + 1, 4)).copy()
    return Scene("cubes", geometry, positions, quaternions)


def test_a_resting_object_falls_asleep_and_stays_put():
    scene = cube_scene([[0, 0, 0.5]], [[0, 0, 0]])
    awake = DriftingSimulator()
    positions, _ = rollout(awake, scene, 500)
    assert abs(positions[-1, 1, 0] - positions[1, 1, 0]) > 1.0  # without sleeping it creeps away (2.5 m)
    asleep = DriftingSimulator()
    positions, _ = rollout(asleep, scene, 500, guards=Guards(sleep=SleepSettings()))
    assert abs(positions[-1, 1, 0] - positions[1, 1, 0]) < 2e-3
    assert len(asleep.static_seen) <= SleepSettings().frames + 1  # then no step was simulated at all
    np.testing.assert_array_equal(positions[-1], positions[-100])


def test_a_moving_object_does_not_sleep():
    scene = cube_scene([[0, 0, 0.5]], [[0.3, 0, 0]])  # 0.3 m/s > 0.02 * sqrt(9.81 * 1.73) = 0.08 m/s
    simulator = DriftingSimulator(drift=0.0)
    positions, _ = rollout(simulator, scene, 60, guards=Guards(sleep=SleepSettings()))
    assert len(simulator.static_seen) == 60
    np.testing.assert_allclose(positions[-1, 1, 0], 0.3 * 60 / 30, rtol=1e-9)


def test_an_asleep_object_is_static_until_something_comes_near_and_then_moves():
    # cube 1 rests at x = 0; cube 2 slides towards it from x = 8 at 3 m/s
    scene = cube_scene([[0, 0, 0.5], [8, 0, 0.5]], [[0, 0, 0], [-3, 0, 0]])
    simulator = DriftingSimulator(drift=0.0)
    positions, _ = rollout(simulator, scene, 80, guards=Guards(sleep=SleepSettings(frames=5)))
    seen = np.array(simulator.static_seen)
    assert seen[10:30, 1].all() and not seen[10:30, 2].any()  # cube 1 asleep (static), cube 2 simulated
    woke = int(np.argmin(seen[10:, 1])) + 10
    gap = np.linalg.norm(positions[1 + woke, 2] - positions[1 + woke, 1]) - 2 * np.sqrt(3) / 2
    assert gap < simulator.config.graph.collision_radius + 0.2  # woken as cube 2 came within the radius
    assert positions[-1, 1, 1] > 0.05  # and then pushed


class StillSimulator:
    """Every object stays where it is; records the static flags it is given."""

    config = SimulatorConfig()

    def __init__(self):
        self.static_seen = []

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        return (*self.step(geometry, positions, quaternions, free_flight), None, None)

    def step(self, geometry, positions, quaternions, free_flight=None):
        self.static_seen.append(geometry.static.copy())
        return positions[1].copy(), quaternions[1].copy()


def test_neighbours_that_come_to_rest_a_frame_apart_fall_asleep_together():
    """Cube 2 stops one frame after cube 1, 0.1 m from it: each used to wake the other (and
    restart its count) as it fell asleep, so neither ever slept."""
    scene = cube_scene([[0, 0, 0.5], [1.1, 0, 0.5]], [[0, 0, 0], [1.0, 0, 0]])
    simulator = StillSimulator()
    positions, _ = rollout(simulator, scene, 100, guards=Guards(sleep=SleepSettings()))
    assert len(simulator.static_seen) <= SleepSettings().frames + 2
    np.testing.assert_array_equal(positions[-1], positions[1])


def test_sleeping_is_off_unless_asked():
    scene = cube_scene([[0, 0, 0.5]], [[0, 0, 0]])
    simulator = DriftingSimulator()
    rollout(simulator, scene, 30)
    assert len(simulator.static_seen) == 30 and not any(s[1] for s in simulator.static_seen)


def test_the_threshold_is_a_froude_number():
    small = dataclasses.replace(SleepSettings(), dt=1 / 30)
    from fignetctl.core.model.rollout import Sleepers

    big_scene, tiny_scene = cube_scene([[0, 0, 0.5]], [[0, 0, 0]]), cube_scene([[0, 0, 0.5]], [[0, 0, 0]])
    tiny_geometry = dataclasses.replace(
        tiny_scene.geometry, rest_vertices=tiny_scene.geometry.rest_vertices * 0.01
    )
    big, tiny = Sleepers(big_scene.geometry, small, 0.2), Sleepers(tiny_geometry, small, 0.2)
    np.testing.assert_allclose(big.threshold[1] / tiny.threshold[1], np.sqrt(100.0))
