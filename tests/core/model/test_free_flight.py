"""Free flight: an object with no collision edge moves exactly, whatever the network says."""

import dataclasses

import numpy as np
import pytest
import torch

from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.rollout import Guards, rollout
from fignetctl.core.model.scene_graph import build_scene_graph
from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig, free_flight_poses
from fignetctl.core.transforms import quat_angle_deg, quat_from_axis_angle, quat_multiply
from tests.core.model.test_sleeping import cube_scene

DT = 1 / 30
GRAVITY = np.array([0.0, 0.0, -10.0])
AXIS = np.array([2.0, -1.0, 2.0]) / 3.0


def exact_pose(t, start, velocity, spin, start_quaternion):
    """Centre and orientation at time t of a body thrown from `start` with `velocity`, turning
    at `spin` rad/s about AXIS."""
    position = start + velocity * t + 0.5 * GRAVITY * t**2
    return position, quat_multiply(quat_from_axis_angle(AXIS, spin * t), start_quaternion)


def untrained_simulator(scene):
    """Random weights; normalizers given statistics from the scene's first step."""
    torch.manual_seed(0)
    simulator = LearnedSimulator(SimulatorConfig(network=PRESETS["tiny"]))
    history = three_frames(scene)
    simulator(build_scene_graph(scene.geometry, *history, simulator.config.graph).graph, accumulate=True)
    simulator.normalized_targets(torch.randn(64, 3, dtype=torch.float32) * 0.01, accumulate=True)
    return simulator.eval()


def three_frames(scene):
    """Frames t−1, t and t (read for static objects only) of a scene's first two frames."""
    return (
        np.concatenate([scene.positions[:2], scene.positions[1:2]]),
        np.concatenate([scene.quaternions[:2], scene.quaternions[1:2]]),
    )


def test_free_flight_poses_follow_the_exact_throw_for_many_steps():
    start, velocity, spin = np.array([1.0, -2.0, 30.0]), np.array([3.0, 1.0, 4.0]), 7.0
    q0 = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 0.4)
    poses = [exact_pose(k * DT, start, velocity, spin, q0) for k in (0, 1)]
    positions = [poses[0][0], poses[1][0]]
    quaternions = [poses[0][1], poses[1][1]]
    for _ in range(60):
        p, q = free_flight_poses(
            np.array(positions[-2:])[:, None], np.array(quaternions[-2:])[:, None], GRAVITY * DT**2
        )
        positions.append(p[0])
        quaternions.append(q[0])
    position, quaternion = exact_pose(61 * DT, start, velocity, spin, q0)
    np.testing.assert_allclose(positions[-1], position, atol=1e-9)
    assert quat_angle_deg(quaternions[-1], quaternion) < 1e-6


def spinning(scene, obj, spin):
    """The scene with object `obj` turning at `spin` rad/s about AXIS between its two frames."""
    quaternions = scene.quaternions.copy()
    quaternions[0, obj] = quat_from_axis_angle(AXIS, -spin * DT)
    return dataclasses.replace(scene, quaternions=quaternions)


def test_an_object_far_from_everything_flies_and_one_on_the_floor_gets_the_network():
    # cube 1 high in the air, cube 2 resting on the floor (its faces within the radius of the floor's)
    scene = spinning(cube_scene([[0, 0, 6.0], [5, 0, 0.5]], [[1, 0, 2], [0, 0, 0]]), 1, 4.0)
    simulator = untrained_simulator(scene)
    history = three_frames(scene)
    network = simulator.step(scene.geometry, *history)
    flying = simulator.step(scene.geometry, *history, free_flight=GRAVITY * DT**2)
    expected = free_flight_poses(scene.positions, scene.quaternions, GRAVITY * DT**2)
    np.testing.assert_allclose(flying[0][1], expected[0][1], atol=1e-12)
    assert quat_angle_deg(flying[1][1], expected[1][1]) < 1e-9
    assert np.linalg.norm(network[0][1] - expected[0][1]) > 1e-4  # an untrained network gets it wrong
    np.testing.assert_array_equal(flying[0][2], network[0][2])  # the touching cube is the network's
    np.testing.assert_array_equal(flying[1][2], network[1][2])


def test_the_network_is_not_run_while_nothing_touches(monkeypatch):
    scene = cube_scene([[0, 0, 6.0]], [[1, 0, 0]])
    scene.positions[0, 1] += 0.5 * GRAVITY * DT**2  # frames 0 and 1 on the parabola
    simulator = untrained_simulator(scene)

    def refuse(*_):
        raise AssertionError("the network ran")

    monkeypatch.setattr(simulator, "forward", refuse)
    positions, _ = rollout(simulator, scene, 20, guards=Guards(free_flight=tuple(GRAVITY * DT**2)))
    position, _ = exact_pose(
        20 * DT, scene.positions[1, 1], np.array([1.0, 0, 0]), 0.0, scene.quaternions[1, 1]
    )
    np.testing.assert_allclose(positions[-1, 1], position, atol=1e-9)
    with pytest.raises(AssertionError, match="the network ran"):
        rollout(simulator, scene, 1)  # without free flight the network moves it
