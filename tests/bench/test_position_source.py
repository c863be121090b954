"""benchmarks/position_source.py: a velocity-state model's next positions from its velocity output."""

import dataclasses

import numpy as np
import pytest
import torch

import fignetctl.core.model.simulator as simulator_module
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import scene_from_trajectory
from fignetctl.core.model.scene_graph import build_scene_graph
from fignetctl.core.model.simulator import LearnedSimulator, integrate
from fignetctl.core.model.training import simulator_config_for
from tests.bench import load_benchmark
from tests.conftest import box_drop_file

position_source = load_benchmark("position_source")


def test_each_source_sets_the_position_step_and_leaves_the_velocity_step():
    rng = np.random.default_rng(0)
    acceleration = rng.normal(size=(5, 6))
    a_x, a_u = acceleration[:, :3], acceleration[:, 3:]
    steps = {
        source: position_source.position_step(acceleration, source) for source in position_source.SOURCES
    }
    np.testing.assert_array_equal(steps["position"], acceleration)
    np.testing.assert_allclose(steps["velocity"][:, :3], a_u / 2)
    np.testing.assert_allclose(steps["mean"][:, :3], (a_x + a_u / 2) / 2)
    for step in steps.values():
        np.testing.assert_array_equal(step[:, 3:], a_u)
    with pytest.raises(ValueError, match="choose one of"):
        position_source.position_step(acceleration, "both")


def test_the_velocity_source_is_the_trapezoid_rule_and_exact_in_free_fall():
    """x_{t+1} = x_t + (u_t + u_{t+1}) / 2; under gravity alone that is the parabola's next point."""
    gravity_step = np.array([0.0, 0.0, -10.0]) / 30**2
    previous, now = np.array([[0.0, 0.0, 5.0]]), np.array([[0.1, 0.0, 5.0]])
    acceleration = np.concatenate([[gravity_step * 0.3], [gravity_step]], axis=1)  # a wrong a_x
    with position_source.positions_from("velocity"):
        next_vertices, next_velocity = simulator_module.integrate(acceleration, previous, now)
    velocity = now - previous
    np.testing.assert_allclose(next_vertices, now + (velocity + next_velocity) / 2)
    np.testing.assert_allclose(next_vertices, now + velocity + gravity_step / 2)
    assert simulator_module.integrate is integrate  # put back after the block


def velocity_state_model(data, scene):
    """Random tiny weights; normalizers from the scene's first step."""
    torch.manual_seed(0)
    config = simulator_config_for("fignet-star", "tiny", 0.5, state="velocities")
    simulator = LearnedSimulator(dataclasses.replace(config, dt=data.dt, gravity=tuple(data.gravity)))
    velocities = (scene.velocities[1] * data.dt, scene.angular_velocities[1] * data.dt)
    graph = build_scene_graph(
        scene.geometry, scene.positions[:3], scene.quaternions[:3], config.graph, velocities
    )
    simulator(graph.graph, accumulate=True)
    simulator.normalized_targets(torch.randn(64, 6) * 0.01, accumulate=True)
    return simulator.eval()


def test_a_rollout_changes_only_when_the_positions_come_from_elsewhere():
    data = box_drop_file(frames=12, dt=1 / 30, height=5.0)
    scene = scene_from_trajectory(data, "00000", simulator_module.SimulatorConfig())
    simulator = velocity_state_model(data, scene)
    plain = rollout(simulator, scene, 8, with_velocities=True)
    runs = {}
    for source in position_source.SOURCES:
        with position_source.positions_from(source):
            runs[source] = rollout(simulator, scene, 8, with_velocities=True)
    for plain_part, position_part in zip(plain, runs["position"]):
        np.testing.assert_array_equal(plain_part, position_part)
    assert not np.allclose(runs["velocity"][0], plain[0])
    # halfway between the two sources after one step (shape matching is linear in a translation)
    np.testing.assert_allclose(
        runs["mean"][0][2, 1], (runs["velocity"][0][2, 1] + plain[0][2, 1]) / 2, atol=1e-6
    )


def test_the_trapezoid_rule_leaves_nothing_of_a_parabola_and_half_a_mid_frame_bounce():
    """Constant acceleration: a_x = a_u / 2 exactly. A bounce a fraction f into a frame (the
    velocity −v to +v, recorded at the frame's ends): the recorded a_x is 2v(1 − f) and the
    rule's a_u / 2 is v, so nothing is left at f = 1/2 and v / 2 at f = 1/4."""
    steps = np.arange(6)[:, None, None]
    gravity, velocity = np.array([0.0, 0.0, -0.01]), np.array([0.3, 0.0, 0.2])
    vertices = velocity * steps + gravity * steps**2 / 2
    velocities = velocity + gravity * steps + 0 * vertices
    a_x, residual = position_source.trapezoid_residuals(vertices, velocities)
    np.testing.assert_allclose(a_x, np.broadcast_to(gravity / 2, a_x.shape), atol=1e-12)
    np.testing.assert_allclose(residual, 0.0, atol=1e-12)
    v = 1.0
    for fraction, left in ((0.5, 0.0), (0.25, 0.5)):  # falls for `fraction` of the frame, then rises
        start = np.array([[[0.0, 0.0, v * fraction]]])
        end = np.array([[[0.0, 0.0, v * (1 - fraction)]]])
        u = np.array([[[0.0, 0.0, -v]]]), np.array([[[0.0, 0.0, v]]])
        a_x, residual = position_source.trapezoid_residuals(np.concatenate([start, end]), np.concatenate(u))
        np.testing.assert_allclose(a_x[0, 0, 2], v * (1 - fraction) - v * fraction + v)
        np.testing.assert_allclose(residual[0, 0, 2], left * v)


def test_a_free_motion_model_s_whole_step_follows_the_rule():
    """The rule applies to the network's answer plus the computed free motion, not to the answer alone."""
    previous, now = np.zeros((2, 3)), np.full((2, 3), 0.1)
    answer, free_motion = np.full((2, 6), 0.02), np.tile([0.0, 0.0, -0.005, 0.0, 0.0, -0.01], (2, 1))
    with position_source.positions_from("velocity"):
        next_vertices, next_velocity = simulator_module.integrate(answer, previous, now, free_motion)
    np.testing.assert_allclose(next_vertices, now + ((now - previous) + next_velocity) / 2)
    np.testing.assert_allclose(next_velocity, (now - previous) + answer[:, 3:] + free_motion[:, 3:])
