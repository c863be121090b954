"""Averaging the network over turns about gravity: the turned graph equals the graph of the
turned scene, and the averaged prediction is exactly equivariant to its turns."""

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from fignetctl.core.model.scene_graph import GraphConfig, build_scene_graph, rotated_graph, scene_geometry
from fignetctl.core.model.simulator import MAX_ROTATIONS, LearnedSimulator, rotations_about_gravity
from fignetctl.core.model.training import simulator_config_for
from fignetctl.core.transforms import matrix_to_quat, quat_multiply, random_quaternions
from fignetctl.errors import FignetError
from tests.core.model.test_scene_graph import FLOOR

GRAVITY = (0.0, 0.0, -10.0)
VELOCITY_TINY = dataclasses.replace(
    simulator_config_for("fignet-star", "tiny", 0.3, state="velocities", static_receivers=False),
    dt=1 / 60,
    gravity=GRAVITY,
)


def _stones_on_floor():
    """Two irregular stones falling onto the floor and onto each other, poses at t−1, t, t+1.
    Irregular so that no face has two vertices equally far from its closest point: those are
    ordered by their coordinates, which a turn changes (`rotated_graph`)."""
    rng = np.random.default_rng(5)
    stones = [trimesh.convex.convex_hull(rng.normal(size=(30, 3)) * 0.4) for _ in range(2)]
    meshes = [FLOOR] + [(stone.vertices, stone.faces) for stone in stones]
    geometry = scene_geometry(
        meshes, [1, 1, 1], [True, False, False], [[0, 0.3, 0.5], [1.0, 0.5, 0.5], [2.0, 0.8, 0.7]]
    )
    quaternions = np.stack([random_quaternions(rng, 3)] * 3)
    quaternions[:, 0] = [1, 0, 0, 0]
    positions = np.array([[0, 0, 0], [0.1, 0.0, 0.6], [0.3, 0.1, 1.5]], float)
    positions = np.stack([positions, positions + [0.01, 0, -0.02], positions + [0.02, 0, -0.04]])
    positions[:, 0] = 0.0
    positions[2, 0] = [0.01, -0.02, 0.0]  # the floor slides over the step: kinematic displacement
    return geometry, positions, quaternions


def _turned(matrix, positions, quaternions, velocities=None):
    """A scene's poses (and velocities) turned by `matrix` (3, 3) about the origin."""
    turn = np.broadcast_to(matrix_to_quat(matrix), quaternions.shape)
    turned = (positions @ matrix.T, quat_multiply(turn, quaternions))
    if velocities is None:
        return turned
    return (*turned, tuple(v @ matrix.T for v in velocities))


def _edges_by_nodes(edge_set):
    """Features of an edge set in an order that does not depend on how the broad phase found them."""
    keys = torch.cat(
        [
            edge_set.senders.reshape(len(edge_set.features), -1),
            edge_set.receivers.reshape(len(edge_set.features), -1),
        ],
        1,
    )
    order = np.lexsort(keys.numpy().T[::-1])
    return keys[order], edge_set.features[order]


@pytest.mark.parametrize("gravity", [GRAVITY, (3.0, -4.0, -5.0), None])
def test_turns_about_gravity_are_proper_rotations_that_keep_gravity_and_step_evenly(gravity):
    turns = rotations_about_gravity(6, gravity).double()
    axis = torch.tensor([0.0, 0.0, -1.0] if gravity is None else gravity, dtype=torch.float64)
    torch.testing.assert_close(turns[0], torch.eye(3, dtype=torch.float64))
    for turn in turns:
        torch.testing.assert_close(turn @ turn.T, torch.eye(3, dtype=torch.float64), atol=1e-6, rtol=0)
        assert torch.linalg.det(turn).item() == pytest.approx(1.0, abs=1e-6)
        torch.testing.assert_close(turn @ axis, axis, atol=1e-5, rtol=0)
    for k in range(6):  # the k-th turn is the first one k times: even steps, all the way round
        torch.testing.assert_close(torch.linalg.matrix_power(turns[1], k), turns[k], atol=1e-5, rtol=0)
    assert not torch.allclose(turns[1], turns[0], atol=0.1)


def test_a_turned_graph_is_the_graph_of_the_turned_scene():
    geometry, positions, quaternions = _stones_on_floor()
    config = GraphConfig(0.3, surface_edges=True, contact_velocity=True, inertia=True)
    matrix = rotations_about_gravity(7, GRAVITY)[3].double().numpy()
    built = build_scene_graph(geometry, positions, quaternions, config).graph
    turned_scene = build_scene_graph(geometry, *_turned(matrix, positions, quaternions), config).graph
    turned = rotated_graph(built, torch.from_numpy(matrix).float())
    torch.testing.assert_close(turned.node_features, turned_scene.node_features, atol=2e-6, rtol=0)
    assert not torch.allclose(turned.node_features, built.node_features, atol=1e-3)  # the scene moves
    assert set(turned.edge_sets) == set(turned_scene.edge_sets) == {*built.edge_sets}
    for name, edge_set in turned.edge_sets.items():
        keys, features = _edges_by_nodes(edge_set)
        expected_keys, expected = _edges_by_nodes(turned_scene.edge_sets[name])
        assert torch.equal(keys, expected_keys), name
        torch.testing.assert_close(features, expected, atol=2e-6, rtol=0, msg=name)


def _simulator_with_statistics(rotations):
    torch.manual_seed(0)
    simulator = LearnedSimulator(VELOCITY_TINY).eval()
    geometry, positions, quaternions = _stones_on_floor()
    simulator(build_scene_graph(geometry, positions, quaternions, VELOCITY_TINY.graph).graph, accumulate=True)
    simulator.normalized_targets(torch.randn(64, 6) * 0.01, accumulate=True)
    simulator.rotations = rotations
    return simulator, geometry, positions, quaternions


@pytest.mark.parametrize("rotations", [1, 4, 6])
def test_the_averaged_prediction_turns_with_the_scene(rotations):
    simulator, geometry, positions, quaternions = _simulator_with_statistics(rotations)
    velocities = (
        np.array([[0, 0, 0], [0.3, -0.2, -1.0], [0.0, 0.4, -2.0]]),
        np.array([[0, 0, 0], [1.0, 2.0, 0.5], [0.0, -1.0, 3.0]]),
    )
    matrix = rotations_about_gravity(max(rotations, 4), GRAVITY)[1].double().numpy()
    here = simulator.predict(geometry, positions, quaternions, velocities=velocities)
    turned_positions, turned_quaternions, turned_velocities = _turned(
        matrix, positions, quaternions, velocities
    )
    there = simulator.predict(geometry, turned_positions, turned_quaternions, velocities=turned_velocities)
    gaps = [np.abs(there[i] - here[i] @ matrix.T).max() for i in (0, 2, 3)]  # positions, v, ω
    if rotations == 1:  # an untrained network is far from equivariant: the test can tell
        assert max(gaps) > 1e-3
    else:
        assert max(gaps) < 1e-5


def test_one_rotation_is_the_network_as_it_is_and_more_change_the_answer():
    simulator, geometry, positions, quaternions = _simulator_with_statistics(1)
    graph = build_scene_graph(geometry, positions, quaternions, VELOCITY_TINY.graph).graph
    plain = simulator.acceleration_normalizer.inverse(simulator(graph))
    assert torch.equal(simulator.network_acceleration(graph), plain)
    simulator.rotations = 3
    averaged = simulator.network_acceleration(graph)
    assert averaged.shape == plain.shape
    assert not torch.allclose(averaged, plain, atol=1e-4)
    copy = simulator.with_graph_config(collision_radius=0.25)
    assert copy.rotations == 3
    copy.rotations = np.int64(2)  # any whole number will do
    assert copy.network_acceleration(graph).shape == plain.shape
    for wrong in (0, 2.5, True, MAX_ROTATIONS + 1):
        copy.rotations = wrong
        with pytest.raises(FignetError, match="from 1 to 64"):
            copy.network_acceleration(graph)


def test_rollout_and_evaluate_bound_the_turns_as_the_model_does():
    """The commands' --rotations declare their bound without importing torch; it must be the model's."""
    from fignetctl.stages import evaluate, rollout

    for stage in (rollout, evaluate):
        field = {f.name: f for f in dataclasses.fields(stage.Settings)}["rotations"]
        assert (field.metadata["low"], field.metadata["high"]) == (1, MAX_ROTATIONS)
