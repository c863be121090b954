"""Per-object targets (`--target objects`): each dynamic object's pose and velocity corrections,
decoded at its object node. Exact inverses between targets and integration, free flight as the
zero correction, training examples that reproduce the recorded next frame, and a model whose
prediction is the integration of what its object nodes decode."""

import dataclasses

import numpy as np
import pytest
import torch

from fignetctl.core.model.scene_data import scene_from_trajectory
from fignetctl.core.model.scene_graph import build_scene_graph
from fignetctl.core.model.simulator import (
    LearnedSimulator,
    SimulatorConfig,
    free_flight_state,
    integrate_objects,
    object_targets,
)
from fignetctl.core.model.training import (
    TrainingSettings,
    output_rows,
    simulator_config_for,
    training_example,
)
from fignetctl.core.transforms import quat_angle_deg, quat_normalize
from tests.conftest import box_drop_file

OBJECT_TINY = dataclasses.replace(
    simulator_config_for(
        "fignet-star", "tiny", 0.1, state="velocities", static_receivers=False, target="objects"
    ),
    dt=1 / 60,
    gravity=(0.0, 0.0, -10.0),
)


def random_states(rng, count):
    """Two states (positions, quaternions, linear, angular) whose turn is under π."""
    state = (
        rng.normal(size=(count, 3)),
        quat_normalize(rng.normal(size=(count, 4))),
        rng.normal(scale=0.1, size=(count, 3)),
        rng.normal(scale=0.3, size=(count, 3)),
    )
    acceleration = rng.normal(scale=0.2, size=(count, 12))
    return state, integrate_objects(acceleration, state), acceleration


def test_targets_and_integration_are_exact_inverses():
    state, next_state, acceleration = random_states(np.random.default_rng(0), 30)
    targets = object_targets(next_state, state)
    assert targets.shape == (30, 12)
    np.testing.assert_allclose(targets, acceleration, atol=1e-12)
    again = integrate_objects(targets, state)
    for value, expected in zip(again[::2], next_state[::2]):
        np.testing.assert_allclose(value, expected, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(again[1] * next_state[1], axis=1)), 1.0, atol=1e-12)


def test_postprocess_undoes_inverse_postprocess():
    simulator = LearnedSimulator(OBJECT_TINY)
    state, next_state, _ = random_states(np.random.default_rng(1), 40)
    normalized = simulator.inverse_postprocess_objects(next_state, state, accumulate=True)
    assert normalized.shape == (40, 12)
    positions, quaternions, linear, angular = simulator.postprocess_objects(normalized, state)
    np.testing.assert_allclose(positions, next_state[0], atol=1e-6)  # float32 targets
    assert quat_angle_deg(quaternions, next_state[1]).max() < 1e-3
    np.testing.assert_allclose(linear, next_state[2], atol=1e-6)
    np.testing.assert_allclose(angular, next_state[3], atol=1e-6)


def test_free_flight_is_half_gravity_and_gravity_with_no_turn():
    rng = np.random.default_rng(2)
    state = (rng.normal(size=(5, 3)), quat_normalize(rng.normal(size=(5, 4))), *rng.normal(size=(2, 5, 3)))
    gravity_step = np.array([0.0, 0.0, -9.81]) / 30**2
    targets = object_targets(free_flight_state(*state, gravity_step), state)
    np.testing.assert_allclose(targets[:, :3], np.tile(gravity_step / 2, (5, 1)), atol=1e-12)
    np.testing.assert_allclose(targets[:, 6:9], np.tile(gravity_step, (5, 1)), atol=1e-12)
    np.testing.assert_allclose(targets[:, 3:6], 0.0, atol=1e-12)
    np.testing.assert_allclose(targets[:, 9:], 0.0, atol=1e-12)


def scene(frames=4):
    return scene_from_trajectory(box_drop_file(frames=frames, height=0.6), "00000", SimulatorConfig())


def test_a_clean_training_example_integrates_to_the_recorded_next_frame():
    box = scene()
    clean = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    scene_graph, targets = training_example(OBJECT_TINY, box, 1, torch.Generator().manual_seed(0), clean)
    assert targets.shape == (1, 12)  # the box; the floor is static
    rows = scene_graph.output_rows("objects")
    assert len(rows) == 1 and scene_graph.node_vertex[rows[0]] == -1  # the object node
    state = (
        box.positions[1, 1:],
        box.quaternions[1, 1:],
        box.velocities[1, 1:] * box.dt,
        box.angular_velocities[1, 1:] * box.dt,
    )
    positions, quaternions, linear, angular = integrate_objects(targets.double().numpy(), state)
    np.testing.assert_allclose(positions, box.positions[2, 1:], atol=1e-6)
    assert quat_angle_deg(quaternions, box.quaternions[2, 1:]).max() < 1e-3
    np.testing.assert_allclose(linear / box.dt, box.velocities[2, 1:], atol=1e-4)
    np.testing.assert_allclose(angular / box.dt, box.angular_velocities[2, 1:], atol=1e-4)


def test_the_target_keeps_the_position_jitter_and_undoes_the_velocity_noise():
    """Frame t jittered, frame t+1 moved by the same rigid jitter, the velocity noisy: both the
    position and the velocity correction differ from the clean ones by minus the velocity noise
    alone, so the position jitter is kept (a resting object is not pushed back)."""
    box = scene()
    noisy = TrainingSettings(noise_translation_std=0.01, noise_rotation_std=0.0)
    clean = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    _, targets = training_example(OBJECT_TINY, box, 1, torch.Generator().manual_seed(3), noisy)
    _, clean_targets = training_example(OBJECT_TINY, box, 1, torch.Generator().manual_seed(3), clean)
    position_change, velocity_change = (
        targets[:, :3] - clean_targets[:, :3],
        targets[:, 6:9] - clean_targets[:, 6:9],
    )
    assert velocity_change.abs().max() > 1e-3  # the noise is there
    np.testing.assert_allclose(position_change, velocity_change, atol=1e-6)
    np.testing.assert_allclose(targets[:, 3:6], clean_targets[:, 3:6], atol=1e-6)  # no rotation noise


def test_rows_of_a_batch_are_the_object_nodes_of_each_graph():
    box = scene()
    clean = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    graphs = [training_example(OBJECT_TINY, box, t, torch.Generator(), clean)[0] for t in (1, 2)]
    rows = output_rows(graphs, "objects")
    assert rows.tolist() == [
        graphs[0].graph.num_nodes - 1,
        graphs[0].graph.num_nodes + graphs[1].graph.num_nodes - 1,
    ]
    assert (
        output_rows(graphs).tolist()[-1] == graphs[0].graph.num_nodes + graphs[1].num_dynamic_vertex_nodes - 1
    )


def test_a_model_predicts_the_integration_of_its_object_outputs():
    box = scene()
    torch.manual_seed(0)
    simulator = LearnedSimulator(OBJECT_TINY).eval()
    velocities = (box.velocities[1], box.angular_velocities[1])
    step = tuple(v * box.dt for v in velocities)
    scene_graph = build_scene_graph(
        box.geometry, box.positions[:3], box.quaternions[:3], OBJECT_TINY.graph, step
    )
    simulator(scene_graph.graph, accumulate=True)  # normalizer statistics, as training gathers them
    simulator.normalized_targets(
        torch.randn(8, 12, generator=torch.Generator().manual_seed(1)), accumulate=True
    )
    positions, quaternions, linear, angular = simulator.predict(
        box.geometry, box.positions[:3], box.quaternions[:3], velocities=velocities
    )
    with torch.no_grad():
        outputs = simulator(scene_graph.graph)[torch.from_numpy(scene_graph.output_rows("objects"))]
    state = (box.positions[1, 1:], box.quaternions[1, 1:], step[0][1:], step[1][1:])
    expected = simulator.postprocess_objects(outputs, state)
    np.testing.assert_allclose(positions[1:], expected[0], atol=1e-12)
    np.testing.assert_allclose(quaternions[1:], expected[1], atol=1e-12)
    np.testing.assert_allclose(linear[1:] * box.dt, expected[2], atol=1e-12)
    np.testing.assert_allclose(angular[1:] * box.dt, expected[3], atol=1e-12)
    np.testing.assert_allclose(positions[0], box.positions[2, 0])  # the floor stays
    assert np.all(linear[0] == 0)


def test_per_object_targets_need_the_velocity_state():
    with pytest.raises(ValueError, match="velocity state"):
        simulator_config_for("fignet-star", "tiny", state="positions", target="objects")


def test_a_per_object_model_learns_free_fall_and_rolls_it_out(tmp_path):
    from fignetctl.core.model.rollout import rollout
    from fignetctl.core.model.training import make_trainer
    from fignetctl.core.trajectory import write_trajectories

    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=30, height=8.0))
    config = TrainingSettings(
        steps=300,
        batch_size=2,
        noise_translation_std=0.0,
        noise_rotation_std=0.0,
        normalizer_accumulation_steps=20,
    )
    trainer = make_trainer(path, OBJECT_TINY, config)
    trainer.run()
    scene = trainer.scenes[0]
    positions, _, velocities, angular = rollout(
        trainer.simulator.eval(), scene, 20, with_velocities=True
    )
    np.testing.assert_allclose(positions[:, 1], scene.positions[:22, 1], atol=0.02)  # 6.7 m of fall
    np.testing.assert_allclose(velocities[:, 1], scene.velocities[:22, 1], atol=0.15)
    np.testing.assert_allclose(angular[:, 1], scene.angular_velocities[:22, 1], atol=0.15)


def test_train_and_rollout_commands_take_a_per_object_model(tmp_path):
    from click.testing import CliRunner

    from fignetctl.cli import cli
    from fignetctl.core.model.checkpoint import load_checkpoint
    from fignetctl.core.trajectory import read_trajectories, write_trajectories

    data = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12, height=5.0))
    model = tmp_path / "model.pt"
    train = ["train", str(data), "-o", str(model), "--size", "tiny", "--steps", "2"]
    result = CliRunner().invoke(cli, [*train, "--target", "objects"])
    assert result.exit_code == 0, result.output
    assert load_checkpoint(model).config.target == "objects"
    out = tmp_path / "rollout.h5"
    result = CliRunner().invoke(
        cli, ["rollout", str(data), "--model", str(model), "--steps", "3", "-o", str(out)]
    )
    assert result.exit_code == 0, result.output
    assert (
        read_trajectories(out).trajectories["00000"].positions.shape[0] == 2 + 3
    )  # the two given frames, then the steps
    refused = CliRunner().invoke(cli, [*train, "--target", "objects", "--state", "positions", "--overwrite"])
    assert refused.exit_code != 0 and "--target objects needs --state velocities" in refused.output
    assert refused.output.count("\n") == 1
