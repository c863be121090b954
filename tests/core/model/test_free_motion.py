"""The free-motion model (`SimulatorConfig.free_motion`): the network's output is added to each
vertex's free motion, computed exactly; checked against `free_flight_state` moved vertex by
vertex, through training targets, and through a whole prediction whose network says nothing."""

import dataclasses

import numpy as np
import pytest
import torch

from fignetctl.core.model.scene_data import scene_from_trajectory
from fignetctl.core.model.scene_graph import rigid_point_velocities
from fignetctl.core.model.simulator import (
    LearnedSimulator,
    SimulatorConfig,
    free_flight_state,
    free_motion_corrections,
    free_motion_of,
)
from fignetctl.core.model.training import TrainingSettings, training_example
from fignetctl.core.transforms import quat_from_rotation_vector, quat_to_matrix
from fignetctl.errors import FignetError
from tests.conftest import box_drop_file
from tests.core.model.test_velocity_state import VELOCITY_TINY, random_rigid_motion

FREE_MOTION_TINY = dataclasses.replace(VELOCITY_TINY, free_motion=True)


def test_corrections_are_the_free_flight_state_moved_vertex_by_vertex():
    """Independent reference: each object's next pose and velocity from free_flight_state, its
    points carried along rigidly, and u_t, u_{t+1} from v + ω × r."""
    rng = np.random.default_rng(4)
    centres, linear, angular, owner, points = random_rigid_motion(rng, 5)
    angular *= 0.7  # up to about a radian per step
    gravity_step = np.array([0.0, 0.0, -10.0]) / 30**2
    quaternions = quat_from_rotation_vector(rng.normal(size=(5, 3)))
    next_centres, next_quaternions, next_linear, next_angular = free_flight_state(
        centres, quaternions, linear, angular, gravity_step
    )
    # each point in its object's frame at t, then where the next pose puts it
    rotations, next_rotations = quat_to_matrix(quaternions), quat_to_matrix(next_quaternions)
    local = np.einsum("nji,nj->ni", rotations[owner], points - centres[owner])
    next_points = next_centres[owner] + np.einsum("nij,nj->ni", next_rotations[owner], local)
    u_now = rigid_point_velocities(points, owner, centres, linear, angular)
    u_next = rigid_point_velocities(next_points, owner, next_centres, next_linear, next_angular)
    expected = np.concatenate([next_points - points - u_now, u_next - u_now], axis=1)
    got = free_motion_corrections(points, owner, centres, angular, gravity_step)
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # no spin: gravity alone, half of it in the position part
    still = free_motion_corrections(points, owner, centres, np.zeros_like(angular), gravity_step)
    np.testing.assert_allclose(still[:, :3], np.broadcast_to(gravity_step / 2, (len(points), 3)), atol=1e-15)
    np.testing.assert_allclose(still[:, 3:], np.broadcast_to(gravity_step, (len(points), 3)), atol=1e-15)


def test_a_free_flight_frame_leaves_the_network_nothing_to_do():
    """The spinning box in free fall: its training targets are zero, where the whole correction
    of a model without free motion is gravity and the spin's turn."""
    data = box_drop_file(frames=3, dt=1 / 60, spin=6.0, height=5.0)
    clean = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    targets = {}
    for config in (VELOCITY_TINY, FREE_MOTION_TINY):
        scene = scene_from_trajectory(data, "00000", config)
        _, target = training_example(config, scene, 1, torch.Generator().manual_seed(0), clean)
        targets[config.free_motion] = target.numpy()
    assert np.abs(targets[True]).max() < 1e-6  # float32 recording of an exact throw
    assert np.abs(targets[False]).max() > 10.0 / 60**2  # gravity and the spin's turn, to be learned


def test_a_network_that_answers_zero_flies_the_box_exactly():
    """Through predict: normalizers at mean 0 and std 1, the decoder's last layer zeroed; the box
    sits near nothing, but the free-flight guard is off, so the network runs and its zero is
    added to the free motion."""
    data = box_drop_file(frames=3, dt=1 / 60, spin=6.0, height=5.0)
    simulator = LearnedSimulator(FREE_MOTION_TINY).eval()
    normalizers = [simulator.node_normalizer, simulator.acceleration_normalizer]
    for normalizer in normalizers + list(simulator.edge_normalizers.values()):
        normalizer.count.fill_(1.0)
        normalizer.sum.zero_()
        normalizer.sum_of_squares.fill_(1.0)
    last = simulator.network.decoder[-1]
    torch.nn.init.zeros_(last.weight), torch.nn.init.zeros_(last.bias)
    scene = scene_from_trajectory(data, "00000", simulator.config)
    velocities = (scene.velocities[1], scene.angular_velocities[1])
    frames = slice(0, 3)
    positions, quaternions, linear, angular = simulator.predict(
        scene.geometry, scene.positions[frames], scene.quaternions[frames], velocities=velocities
    )
    dt = simulator.config.dt
    gravity_step = np.asarray(simulator.config.gravity) * dt**2
    expected = free_flight_state(
        scene.positions[1], scene.quaternions[1], velocities[0] * dt, velocities[1] * dt, gravity_step
    )
    box = ~scene.geometry.static
    np.testing.assert_allclose(positions[box], expected[0][box], atol=1e-9)
    np.testing.assert_allclose(np.abs((quaternions[box] * expected[1][box]).sum(1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(linear[box], expected[2][box] / dt, atol=1e-6)
    np.testing.assert_allclose(angular[box], expected[3][box] / dt, atol=1e-6)


def test_free_motion_needs_the_velocity_state_and_the_datas_gravity():
    positions_network = dataclasses.replace(VELOCITY_TINY.network, output_size=3)
    with pytest.raises(ValueError, match="velocity state"):
        dataclasses.replace(VELOCITY_TINY, state="positions", network=positions_network, free_motion=True)
    unrecorded = dataclasses.replace(FREE_MOTION_TINY, gravity=None)
    with pytest.raises(FignetError, match="gravity"):
        free_motion_of(unrecorded, None, None, None, None)
    back = SimulatorConfig.from_json(FREE_MOTION_TINY.to_json())
    assert back == FREE_MOTION_TINY and not SimulatorConfig.from_json(VELOCITY_TINY.to_json()).free_motion


def test_postprocess_undoes_inverse_postprocess_with_free_motion():
    simulator = LearnedSimulator(FREE_MOTION_TINY)
    rng = np.random.default_rng(5)
    previous, now, after, next_velocity = rng.normal(scale=0.1, size=(4, 30, 3))
    free_motion = rng.normal(scale=0.05, size=(30, 6))
    normalized = simulator.inverse_postprocess(
        after, previous, now, next_velocity, accumulate=True, free_motion=free_motion
    )
    plain = simulator.inverse_postprocess(after, previous, now, next_velocity)
    assert not torch.allclose(normalized, plain)  # the free motion is taken out of the target
    next_vertices, next_velocities = simulator.postprocess(normalized, previous, now, free_motion)
    np.testing.assert_allclose(next_vertices, after, atol=1e-6)  # float32 targets
    np.testing.assert_allclose(next_velocities, next_velocity, atol=1e-6)
