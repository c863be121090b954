"""The velocity state: trajectories with instantaneous velocities, the graph's velocity feature,
exact inverses between targets and integration, rigid velocity fits, free flight and rollouts
that carry their velocities."""

import dataclasses

import numpy as np
import pytest
import torch

from fignetctl.core.model.graph import FACE_FACE
from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import scene_from_trajectory
from fignetctl.core.model.scene_graph import GraphConfig, build_scene_graph, rigid_point_velocities
from fignetctl.core.model.simulator import (
    LearnedSimulator,
    SimulatorConfig,
    acceleration_targets,
    free_flight_state,
    integrate,
    rigid_velocities_from_vertices,
)
from fignetctl.core.model.training import TrainingSettings, make_trainer, simulator_config_for
from fignetctl.core.trajectory import estimated_velocities, read_trajectories, write_trajectories
from fignetctl.core.transforms import quat_from_rotation_vector, quat_to_rotation_vector
from fignetctl.errors import FignetError, FormatError
from tests.conftest import box_drop_file

VELOCITY_TINY = dataclasses.replace(
    simulator_config_for("fignet-star", "tiny", 0.1, state="velocities", static_receivers=False),
    dt=1 / 60,
    gravity=(0.0, 0.0, -10.0),
)


def random_rigid_motion(rng, count):
    """Centres (O, 3), linear and angular velocities (O, 3) and points (P, 3) with their objects (P,)."""
    centres = rng.normal(size=(count, 3))
    linear, angular = rng.normal(size=(count, 3)), rng.normal(size=(count, 3))
    owner = np.repeat(np.arange(count), 12)
    points = centres[owner] + rng.normal(size=(len(owner), 3))
    return centres, linear, angular, owner, points


def test_version_2_round_trip_keeps_velocities_and_version_1_reads_without(tmp_path, box_drop):
    path = write_trajectories(tmp_path / "v2.h5", box_drop)
    back = read_trajectories(path).trajectories["00000"]
    np.testing.assert_array_equal(back.velocities, box_drop.trajectories["00000"].velocities)
    np.testing.assert_array_equal(back.angular_velocities, box_drop.trajectories["00000"].angular_velocities)
    import h5py

    with h5py.File(path, "r") as f:
        assert f.attrs["format_version"] == 2
    plain = dataclasses.replace(box_drop.trajectories["00000"], velocities=None, angular_velocities=None)
    path = write_trajectories(
        tmp_path / "plain.h5", dataclasses.replace(box_drop, trajectories={"00000": plain})
    )
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = 1
    assert not read_trajectories(path).trajectories["00000"].has_velocities


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda t: dataclasses.replace(t, angular_velocities=None), "give both or neither"),
        (lambda t: dataclasses.replace(t, velocities=t.velocities[:2]), "must be float"),
        (
            lambda t: dataclasses.replace(
                t, velocities=np.where(np.arange(3)[:, None, None] == 2, np.nan, t.velocities)
            ),
            "not finite at frame 2",
        ),
    ],
)
def test_damaged_velocities_are_refused(tmp_path, box_drop, change, message):
    broken = change(box_drop.trajectories["00000"])
    with pytest.raises(FormatError, match=message):
        write_trajectories(tmp_path / "x.h5", dataclasses.replace(box_drop, trajectories={"00000": broken}))


def test_estimated_velocities_are_exact_for_constant_velocity_and_spin():
    dt, steps = 0.05, 6
    linear, spin = np.array([0.3, -1.0, 2.0]), np.array([0.5, 1.5, -2.0])
    times = np.arange(steps) * dt
    positions = (times[:, None] * linear)[:, None]
    quaternions = quat_from_rotation_vector(times[:, None] * spin)[:, None]
    velocities, angular = estimated_velocities(positions, quaternions, dt)
    np.testing.assert_allclose(velocities[:, 0], np.tile(linear, (steps, 1)), atol=1e-12)
    np.testing.assert_allclose(angular[:, 0], np.tile(spin, (steps, 1)), atol=1e-9)


def test_rotation_vector_round_trip():
    vectors = np.random.default_rng(0).normal(size=(50, 3))
    vectors *= np.minimum(1.0, 3.0 / np.linalg.norm(vectors, axis=1))[:, None]  # inside the short way round
    np.testing.assert_allclose(
        quat_to_rotation_vector(quat_from_rotation_vector(vectors)), vectors, atol=1e-12
    )


def test_targets_and_integration_are_exact_inverses():
    rng = np.random.default_rng(1)
    previous, now, after, next_velocity = rng.normal(size=(4, 20, 3))
    for velocities in (None, next_velocity):
        targets = acceleration_targets(after, previous, now, velocities)
        assert targets.shape == (20, 3 if velocities is None else 6)
        next_vertices, next_velocities = integrate(targets, previous, now)
        np.testing.assert_allclose(next_vertices, after, atol=1e-12)
        if velocities is not None:
            np.testing.assert_allclose(next_velocities, next_velocity, atol=1e-12)
    free_motion = rng.normal(size=(20, 6))  # what a free-motion model's output is added to
    targets = acceleration_targets(after, previous, now, next_velocity, free_motion)
    np.testing.assert_allclose(
        targets + free_motion, acceleration_targets(after, previous, now, next_velocity)
    )
    next_vertices, next_velocities = integrate(targets, previous, now, free_motion)
    np.testing.assert_allclose(next_vertices, after, atol=1e-12)
    np.testing.assert_allclose(next_velocities, next_velocity, atol=1e-12)


def test_postprocess_undoes_inverse_postprocess():
    simulator = LearnedSimulator(VELOCITY_TINY)
    rng = np.random.default_rng(2)
    previous, now, after, next_velocity = rng.normal(scale=0.1, size=(4, 30, 3))
    normalized = simulator.inverse_postprocess(after, previous, now, next_velocity, accumulate=True)
    next_vertices, next_velocities = simulator.postprocess(normalized, previous, now)
    np.testing.assert_allclose(next_vertices, after, atol=1e-6)  # float32 targets
    np.testing.assert_allclose(next_velocities, next_velocity, atol=1e-6)
    free_motion = rng.normal(scale=0.1, size=(30, 6))
    normalized = simulator.inverse_postprocess(after, previous, now, next_velocity, free_motion=free_motion)
    next_vertices, next_velocities = simulator.postprocess(normalized, previous, now, free_motion)
    np.testing.assert_allclose(next_vertices, after, atol=1e-6)
    np.testing.assert_allclose(next_velocities, next_velocity, atol=1e-6)


def test_rigid_velocity_fit_recovers_the_motion_of_each_object():
    rng = np.random.default_rng(3)
    data = box_drop_file(frames=3)
    scene = scene_from_trajectory(data, "00000", SimulatorConfig())
    geometry = scene.geometry
    centres = scene.positions[1]
    vertices = geometry.world_vertices(centres, scene.quaternions[1], geometry.dynamic_vertices)
    linear, angular = rng.normal(size=(2, 2, 3))
    owner = geometry.vertex_object[geometry.dynamic_vertices]
    velocities = rigid_point_velocities(vertices, owner, centres, linear, angular)
    fitted = rigid_velocities_from_vertices(geometry, vertices, velocities, centres)
    np.testing.assert_allclose(fitted[0][1], linear[1], atol=1e-12)
    np.testing.assert_allclose(fitted[1][1], angular[1], atol=1e-12)
    np.testing.assert_array_equal(fitted[0][0], 0.0)  # the static floor


def test_free_flight_state_follows_the_parabola_and_the_spin():
    gravity = np.array([0.0, 0.0, -10.0]) * 0.1**2
    position, quaternion = np.array([[1.0, 2.0, 3.0]]), np.array([[1.0, 0.0, 0.0, 0.0]])
    linear, angular = np.array([[0.1, 0.0, 0.2]]), np.array([[0.0, 0.3, 0.0]])
    state = (position, quaternion, linear, angular)
    for _ in range(7):
        state = free_flight_state(*state, gravity)
    np.testing.assert_allclose(state[0][0], position[0] + 7 * linear[0] + 0.5 * 49 * gravity, atol=1e-12)
    np.testing.assert_allclose(state[2][0], linear[0] + 7 * gravity, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotation_vector(state[1])[0], 7 * angular[0], atol=1e-12)


def test_the_graphs_velocity_feature_is_the_instantaneous_velocity():
    data = box_drop_file(frames=3)
    scene = scene_from_trajectory(data, "00000", SimulatorConfig())
    geometry, dt = scene.geometry, scene.dt
    velocities = (scene.velocities[1] * dt, scene.angular_velocities[1] * dt)
    graph = build_scene_graph(geometry, scene.positions, scene.quaternions, GraphConfig(0.1), velocities)
    vertices = geometry.world_vertices(scene.positions[1], scene.quaternions[1], geometry.dynamic_vertices)
    expected = rigid_point_velocities(
        vertices, geometry.vertex_object[geometry.dynamic_vertices], scene.positions[1], *velocities
    )
    features = graph.graph.node_features.numpy()
    np.testing.assert_allclose(features[: len(expected), :3], expected, atol=1e-6)
    object_node = graph.graph.num_nodes - 1
    np.testing.assert_allclose(features[object_node, :3], velocities[0][1], atol=1e-6)
    finite_difference = build_scene_graph(
        geometry, scene.positions, scene.quaternions, GraphConfig(0.1)
    ).graph.node_features.numpy()
    assert (
        np.abs(finite_difference[: len(expected), :3] - expected).max() > 1e-3
    )  # the falling box: they differ by g·dt/2


@pytest.mark.parametrize("contact_velocity", [False, True])
def test_translating_the_scene_does_not_change_a_velocity_models_prediction(contact_velocity):
    torch.manual_seed(0)
    graph = dataclasses.replace(VELOCITY_TINY.graph, contact_velocity=contact_velocity)
    simulator = LearnedSimulator(dataclasses.replace(VELOCITY_TINY, graph=graph)).eval()
    scene = scene_from_trajectory(box_drop_file(frames=3, height=0.6), "00000", SimulatorConfig())
    velocities = (scene.velocities[1], scene.angular_velocities[1])
    simulator.inverse_postprocess(
        np.ones((4, 3)), np.zeros((4, 3)), np.ones((4, 3)), np.ones((4, 3)), accumulate=True
    )
    build_scene_graph(
        scene.geometry, scene.positions, scene.quaternions, simulator.config.graph
    )  # warm the caches alike
    built = build_scene_graph(
        scene.geometry,
        scene.positions,
        scene.quaternions,
        simulator.config.graph,
        tuple(v * scene.dt for v in velocities),
    ).graph
    assert built.edge_sets[FACE_FACE].num_edges > 0  # the box near the floor: contact edges
    simulator(built, accumulate=True)
    first = simulator.predict(scene.geometry, scene.positions, scene.quaternions, velocities=velocities)
    shift = np.array([1000.0, -2000.0, 0.0])
    moved = simulator.predict(
        scene.geometry, scene.positions + shift, scene.quaternions, velocities=velocities
    )
    np.testing.assert_allclose(moved[0] - shift, first[0], atol=1e-6)
    np.testing.assert_allclose(moved[2], first[2], atol=1e-6)
    np.testing.assert_allclose(moved[3], first[3], atol=1e-6)


def test_a_velocity_model_learns_free_fall_and_its_rollout_carries_velocities(tmp_path):
    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=30, height=8.0))
    config = TrainingSettings(
        steps=300,
        batch_size=2,
        noise_translation_std=0.0,
        noise_rotation_std=0.0,
        normalizer_accumulation_steps=20,
    )
    trainer = make_trainer(path, VELOCITY_TINY, config)
    trainer.run()
    simulator = trainer.simulator.eval()
    scene = trainer.scenes[0]
    positions, _quaternions, velocities, angular = rollout(simulator, scene, 20, with_velocities=True)
    assert velocities.shape == angular.shape == (22, 2, 3)
    np.testing.assert_allclose(
        positions[:, 1], scene.positions[:22, 1], atol=0.02
    )  # the exact fall, 6.7 m of it
    np.testing.assert_allclose(velocities[:, 1], scene.velocities[:22, 1], atol=0.15)  # 6.3 m/s at the end
    np.testing.assert_allclose(angular[:, 1], scene.angular_velocities[:22, 1], atol=0.15)


def test_batches_are_the_same_whichever_process_builds_them(tmp_path):
    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    config = TrainingSettings(steps=4, batch_size=2)
    here = make_trainer(path, VELOCITY_TINY, config, workers=0)
    there = make_trainer(path, VELOCITY_TINY, config, workers=1)
    here.run()
    there.run()
    for name, value in here.simulator.state_dict().items():
        torch.testing.assert_close(there.simulator.state_dict()[name], value, rtol=0, atol=0)


def test_each_process_of_a_data_parallel_run_draws_its_own_batches(tmp_path):
    from fignetctl.core.model.training import TrainingBatches

    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=40))
    scenes = make_trainer(path, VELOCITY_TINY, TrainingSettings(steps=1)).scenes
    config = TrainingSettings(steps=2, batch_size=1)
    first, again, other = (
        TrainingBatches(scenes, VELOCITY_TINY, config, rank)[1]["targets"] for rank in (0, 0, 1)
    )
    torch.testing.assert_close(first, again, rtol=0, atol=0)
    assert not torch.equal(first, other)


def test_velocity_training_needs_recorded_velocities(tmp_path):
    data = box_drop_file(frames=12)
    plain = dataclasses.replace(data.trajectories["00000"], velocities=None, angular_velocities=None)
    path = write_trajectories(tmp_path / "plain.h5", dataclasses.replace(data, trajectories={"00000": plain}))
    with pytest.raises(FignetError, match="no recorded velocities"):
        make_trainer(path, VELOCITY_TINY, TrainingSettings(steps=1))


def test_a_positions_state_is_still_trained_and_stepped(tmp_path):
    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    positions_config = dataclasses.replace(VELOCITY_TINY, state="positions", network=PRESETS["tiny"])
    trainer = make_trainer(path, positions_config, TrainingSettings(steps=2, batch_size=2))
    trainer.run()
    out = rollout(trainer.simulator.eval(), trainer.scenes[0], 3, with_velocities=True)
    assert out[2] is None and np.isfinite(out[0]).all()


def test_a_state_and_an_output_size_that_disagree_are_refused():
    with pytest.raises(ValueError, match="decodes 6 numbers"):
        SimulatorConfig(state="velocities")


@pytest.fixture(scope="module")
def velocity_model(tmp_path_factory):
    """A velocity-state model file trained for a few steps on a 60 fps box drop, and the data."""
    folder = tmp_path_factory.mktemp("velocity")
    data = write_trajectories(folder / "box.h5", box_drop_file(frames=40, height=20.0))
    trainer = make_trainer(data, VELOCITY_TINY, TrainingSettings(steps=3, batch_size=2))
    trainer.run(folder / "model.pt")
    return folder / "model.pt", data


@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_a_rollout_file_carries_velocities_and_maps_them_back_from_the_simulated_size(
    velocity_model, tmp_path, scale
):
    from fignetctl.core.model.apply import rollout_trajectory
    from fignetctl.core.model.checkpoint import load_checkpoint

    model, data = velocity_model
    result = rollout_trajectory(
        load_checkpoint(model), read_trajectories(data), 12, sim_scale=scale, free_flight=True
    )
    assert result.dt == pytest.approx((1 / 60) / scale**0.5)
    box = result.trajectories["00000"]
    times = (
        1 / 60 + np.arange(-1, 13) * result.dt
    )  # frame 1 is at 1/60 s; frame 0 re-timed to one step before
    np.testing.assert_allclose(
        box.positions[1:, 1, 2], 20.0 - 5.0 * times[1:] ** 2, atol=1e-4
    )  # free flight, exact
    np.testing.assert_allclose(box.velocities[1:, 1, 2], -10.0 * times[1:], atol=1e-4)
    np.testing.assert_allclose(
        box.angular_velocities[1:, 1],
        np.tile(box_drop_file().trajectories["00000"].angular_velocities[0, 1], (13, 1)),
        atol=1e-5,
    )


def test_a_velocity_model_steps_at_its_own_time_step_and_a_positions_model_refuses_another(
    velocity_model, tmp_path
):
    from fignetctl.core.model.apply import rollout_trajectory
    from fignetctl.core.model.checkpoint import load_checkpoint

    model, _ = velocity_model
    at_30_fps = write_trajectories(tmp_path / "30fps.h5", box_drop_file(frames=3, dt=1 / 30, height=20.0))
    result = rollout_trajectory(load_checkpoint(model), read_trajectories(at_30_fps), 4, free_flight=True)
    assert result.dt == pytest.approx(1 / 60)
    positions_model = load_checkpoint(model)
    positions_model.config = dataclasses.replace(
        positions_model.config, state="positions", network=PRESETS["tiny"]
    )
    with pytest.raises(FignetError, match="give the scene at dt = 0.0166667"):
        rollout_trajectory(positions_model, read_trajectories(at_30_fps), 4)


def test_a_copy_with_another_collision_radius_shares_the_weights_but_not_the_graphs():
    torch.manual_seed(0)
    simulator = LearnedSimulator(VELOCITY_TINY).eval()
    wider = simulator.with_graph_config(collision_radius=0.5)
    assert wider.config.graph.collision_radius == 0.5 and simulator.config.graph.collision_radius == 0.1
    assert not wider.training and wider.trained_properties is simulator.trained_properties
    for (name, mine), (other_name, theirs) in zip(simulator.state_dict().items(), wider.state_dict().items()):
        assert name == other_name and torch.equal(mine, theirs)
    with pytest.raises(FignetError, match="change the network's inputs"):
        simulator.with_graph_config(surface_edges=True)


class _Oracle:
    """A simulator that predicts frame t of `scene` exactly, shifted by `shift` (m)."""

    def __init__(self, config, scene, frame, shift=0.0):
        self.config, self.scene, self.frame, self.shift = config, scene, frame, shift

    def predict(self, geometry, positions, quaternions, velocities=None):
        np.testing.assert_array_equal(positions[1], self.scene.positions[self.frame - 1])  # the true t−1
        np.testing.assert_array_equal(velocities[0], self.scene.velocities[self.frame - 1])
        moved = np.array(self.scene.positions[self.frame], np.float64)
        moved[~geometry.static] += self.shift
        return (
            moved,
            np.array(self.scene.quaternions[self.frame], np.float64),
            np.array(self.scene.velocities[self.frame], np.float64),
            np.array(self.scene.angular_velocities[self.frame], np.float64),
        )


@pytest.mark.parametrize("keeps_noise", [True, False])
def test_a_pushforward_example_is_the_noise_free_one_from_an_exact_prediction_and_keeps_its_error(
    tmp_path, keeps_noise
):
    from fignetctl.core.model.training import pushforward_example, training_example

    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    config = TrainingSettings(
        noise_translation_std=0.0, noise_rotation_std=0.0, target_keeps_noise=keeps_noise
    )
    scene = make_trainer(path, VELOCITY_TINY, config).scenes[0]
    clean_graph, clean = training_example(VELOCITY_TINY, scene, 5, torch.Generator().manual_seed(0), config)
    exact_graph, exact = pushforward_example(_Oracle(VELOCITY_TINY, scene, 5), scene, 5, config)
    torch.testing.assert_close(exact, clean)
    torch.testing.assert_close(exact_graph.graph.node_features, clean_graph.graph.node_features)
    shift = np.array([0.01, -0.02, 0.005])
    _, shifted = pushforward_example(_Oracle(VELOCITY_TINY, scene, 5, shift), scene, 5, config)
    # x_{t+1} = x_t + u_t + a_x: a target that keeps frame t's error keeps the object where the
    # prediction put it; else it is asked to undo the shift
    expected_position_part = clean[:, :3] - (0 if keeps_noise else torch.tensor(shift, dtype=torch.float32))
    torch.testing.assert_close(shifted[:, :3], expected_position_part)
    torch.testing.assert_close(shifted[:, 3:], clean[:, 3:])


@pytest.mark.parametrize("undone", [0.25, 1.0])
def test_a_target_undoes_the_asked_fraction_of_frame_ts_error_in_position_only(tmp_path, undone):
    """`position_noise_undone` = α: x_{t+1} = x_t + u_t + a_x with a_x moved back by α of frame
    t's error (a shifted prediction here); the velocity part of the target is unchanged."""
    from fignetctl.core.model.training import pushforward_example

    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    kept = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    scene = make_trainer(path, VELOCITY_TINY, kept).scenes[0]
    shift = np.array([0.01, -0.02, 0.005])
    oracle = _Oracle(VELOCITY_TINY, scene, 5, shift)
    _, keeping = pushforward_example(oracle, scene, 5, kept)
    _, undoing = pushforward_example(
        oracle, scene, 5, dataclasses.replace(kept, position_noise_undone=undone)
    )
    torch.testing.assert_close(
        undoing[:, :3], keeping[:, :3] - undone * torch.tensor(shift, dtype=torch.float32)
    )
    torch.testing.assert_close(undoing[:, 3:], keeping[:, 3:])


def test_pushforward_training_predicts_its_own_frames_and_resumes_exactly(tmp_path, monkeypatch):
    from fignetctl.core.model import training

    path = write_trajectories(tmp_path / "box.h5", box_drop_file(frames=12))
    config = TrainingSettings(
        steps=6, batch_size=2, pushforward=1, normalizer_accumulation_steps=2, checkpoint_every=3
    )
    honest, calls = training.pushforward_example, []

    def counted(*args):
        calls.append(1)
        return honest(*args)

    monkeypatch.setattr(training, "pushforward_example", counted)
    straight = make_trainer(path, VELOCITY_TINY, config)
    straight.run()
    assert len(calls) == 4  # one per step once the normalizers froze (steps 2..5)
    assert len(straight.batches[0]["rows"]) == len(
        straight.scenes[0].geometry.dynamic_vertices
    )  # one worker example
    interrupted = make_trainer(path, VELOCITY_TINY, config)
    interrupted.run(tmp_path / "half.pt", until_step=3)
    resumed = make_trainer(path, VELOCITY_TINY, config, resume_from=tmp_path / "half.pt")
    assert resumed.config.pushforward == 1
    resumed.run()
    for name, value in straight.simulator.state_dict().items():
        torch.testing.assert_close(resumed.simulator.state_dict()[name], value, rtol=0, atol=0)
