"""The two-step loss (unroll.py): the second step's graph and targets against graphs built
again from moved poses, its rigid projection against the simulator's least-squares fit, and
training with it."""

import dataclasses
import functools

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from fignetctl.cli import cli
from fignetctl.core.model.scene_data import scenes_from_file
from fignetctl.core.model.scene_graph import FACE_FACE, build_scene_graph
from fignetctl.core.model.simulator import LearnedSimulator, rigid_velocities_from_vertices
from fignetctl.core.model.training import (
    TrainingSettings,
    batch_of,
    later_steps_of,
    make_trainer,
    simulator_config_for,
    training_example,
)
from fignetctl.core.model.unroll import deviated_graph, later_step_inputs, rigid_projection
from fignetctl.core.trajectory import write_trajectories
from fignetctl.core.transforms import quat_from_rotation_vector, quat_multiply
from fignetctl.errors import FignetError
from tests.conftest import box_drop_file

STAR = simulator_config_for(
    "fignet-star", "tiny", 0.2, max_faces=64, state="velocities", static_receivers=False
)
FULL = dataclasses.replace(STAR, graph=dataclasses.replace(STAR.graph, surface_edges=True))


@pytest.fixture(scope="module")
def movi_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("unroll") / "movi.h5"
    made = CliRunner().invoke(
        cli,
        ["make-dataset", "--preset", "movi-b", "-n", "1", "--seed", "5", "--duration", "1", "-o", str(path)],
    )
    assert made.exit_code == 0, made.output
    return path


def _busiest_frame(scene, config):
    """The frame (t+1 of an example) with the most face–face edges, and one with none."""
    counts = [
        build_scene_graph(
            scene.geometry,
            scene.positions[t - 1 : t + 2],
            scene.quaternions[t - 1 : t + 2],
            config.graph,
            (scene.velocities[t] * scene.dt, scene.angular_velocities[t] * scene.dt),
        )
        .graph.edge_sets[FACE_FACE]
        .num_edges
        for t in range(2, len(scene.positions) - 1)
    ]
    return 2 + int(np.argmax(counts))


@pytest.mark.parametrize("config", [STAR, FULL], ids=["fignet-star", "fignet"])
def test_no_deviation_gives_the_recorded_graph_of_the_next_frame(movi_file, config):
    scene = scenes_from_file(movi_file, config)[0]
    frame = _busiest_frame(scene, config) - 1
    first, _ = training_example(config, scene, frame, torch.Generator().manual_seed(0), TrainingSettings())
    (second,) = later_steps_of(config, scene, frame, first, 1.0, TrainingSettings(unroll=2))
    assert second.graph.edge_sets[FACE_FACE].num_edges > 100
    nodes = second.graph.num_nodes
    moved = deviated_graph(second, torch.zeros(nodes, 3), torch.zeros(nodes, 3))
    assert torch.equal(moved.node_features, second.graph.node_features)
    for name, edge_set in second.graph.edge_sets.items():
        torch.testing.assert_close(moved.edge_sets[name].features, edge_set.features, atol=2e-6, rtol=0)


def _moved_object(scene, t, obj, translation, rotation, linear_change):
    """Poses t−1 .. t+1 and velocities (per step) at t with object `obj` moved rigidly at t."""
    positions = np.array(scene.positions[t - 1 : t + 2], np.float64)
    quaternions = np.array(scene.quaternions[t - 1 : t + 2], np.float64)
    positions[1, obj] += translation
    quaternions[1, obj] = quat_multiply(quat_from_rotation_vector(rotation), quaternions[1, obj])
    linear = scene.velocities[t] * scene.dt
    linear[obj] += linear_change
    return positions, quaternions, (linear, scene.angular_velocities[t] * scene.dt)


def test_a_small_rigid_deviation_moves_the_features_as_building_the_graph_again_does(movi_file):
    """One object moved 2 mm and turned 2 mrad at t+1, and its velocity changed: node velocities
    as the rebuilt graph's (without the turn), object offsets to second order, and each face–face edge that both
    graphs have keeps its distance and normals to second order (its closest points stay at
    their barycentric coordinates, where the rebuilt edge's slide: first order)."""
    config = STAR
    scene = scenes_from_file(movi_file, config)[0]
    t = _busiest_frame(scene, config)
    clean = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    first, _ = training_example(config, scene, t - 1, torch.Generator().manual_seed(0), clean)
    (second,) = later_steps_of(config, scene, t - 1, first, 1.0, dataclasses.replace(clean, unroll=2))
    faces = second.graph.edge_sets[FACE_FACE]
    dynamic_objects = np.flatnonzero(~scene.geometry.static)
    obj_local = int(second.vertex_object[faces.receivers[0, 0]])  # an object in contact
    obj = int(dynamic_objects[obj_local])
    translation, rotation = np.array([0.002, -0.001, 0.0015]), np.array([0.0, 0.002, -0.001])
    linear_change = np.array([0.001, 0.0, -0.002])
    positions, quaternions, velocities = _moved_object(scene, t, obj, translation, rotation, linear_change)
    rebuilt = build_scene_graph(scene.geometry, positions, quaternions, config.graph, velocities)

    rows = second.vertex_object == obj_local
    offsets = second.offsets[rows].double()
    shift = torch.zeros(second.graph.num_nodes, 3, dtype=torch.float64)
    shift[second.rows[rows]] = torch.from_numpy(translation) + torch.linalg.cross(
        torch.from_numpy(rotation).expand_as(offsets), offsets, dim=1
    )
    shift[second.object_rows[obj_local]] = torch.from_numpy(translation)
    velocity = torch.zeros_like(shift)
    velocity[second.rows[rows]] = torch.from_numpy(linear_change)
    velocity[second.object_rows[obj_local]] = torch.from_numpy(linear_change)
    moved = deviated_graph(second, shift.float(), velocity.float())

    # the vertices' velocities: a turned object's spin moves its vertices differently (ω × (θ × r)),
    # which the deviation leaves out; without the turn they are exact
    positions, quaternions, velocities = _moved_object(
        scene, t, obj, translation, 0 * rotation, linear_change
    )
    unturned = build_scene_graph(scene.geometry, positions, quaternions, config.graph, velocities)
    torch.testing.assert_close(moved.node_features, unturned.graph.node_features, atol=1e-6, rtol=0)
    for name in ("mesh_to_object", "object_to_mesh"):
        torch.testing.assert_close(
            moved.edge_sets[name].features, rebuilt.graph.edge_sets[name].features, atol=1e-5, rtol=0
        )
    ours = {
        key: row
        for row, key in enumerate(
            zip(map(tuple, faces.senders.tolist()), map(tuple, faces.receivers.tolist()))
        )
    }
    theirs = rebuilt.graph.edge_sets[FACE_FACE]
    pairs = [
        (ours[key], row)
        for row, key in enumerate(
            zip(map(tuple, theirs.senders.tolist()), map(tuple, theirs.receivers.tolist()))
        )
        if key in ours
    ]
    touched = [
        (a, b) for a, b in pairs if bool(shift[faces.senders[a]].any() or shift[faces.receivers[a]].any())
    ]
    assert len(touched) > 20
    a, b = (torch.tensor(rows) for rows in zip(*touched))
    before = faces.features[a]
    after, expected = moved.edge_sets[FACE_FACE].features[a], theirs.features[b]
    distance_change = (expected[:, 3] - before[:, 3]).abs()
    assert distance_change.max() > 5e-4  # the deviation changes these distances
    apart = before[:, 3] > 0  # faces that intersect (distance 0) have no smooth distance to follow
    assert apart.sum() > 20
    error = (after[:, 3] - expected[:, 3]).abs()[apart]
    assert (error <= 0.15 * distance_change[apart] + 2e-5).all()
    torch.testing.assert_close(after[:, 28:34], expected[:, 28:34], atol=1e-5, rtol=0)


def test_the_rigid_projection_is_the_simulators_least_squares_fit():
    rng = np.random.default_rng(0)
    owner = np.repeat([0, 1, 2], [5, 7, 4])
    offsets = rng.normal(size=(len(owner), 3))
    field = rng.normal(size=(len(owner), 3))

    class Geometry:  # what rigid_velocities_from_vertices reads
        num_objects = 3
        static = np.zeros(3, bool)
        dynamic_vertices = np.arange(len(owner))
        vertex_object = owner

    linear, angular = rigid_velocities_from_vertices(Geometry, offsets, field, np.zeros((3, 3)))
    expected = linear[owner] + np.cross(angular[owner], offsets)
    from fignetctl.core.model.unroll import _inverse_normal_matrices

    inverse = torch.from_numpy(_inverse_normal_matrices(offsets, owner, 3))
    per_vertex, centres = rigid_projection(
        torch.from_numpy(field), torch.from_numpy(owner), torch.from_numpy(offsets), inverse
    )
    np.testing.assert_allclose(per_vertex.numpy(), expected, atol=1e-12)
    np.testing.assert_allclose(centres.numpy(), linear, atol=1e-12)
    again, _ = rigid_projection(per_vertex, torch.from_numpy(owner), torch.from_numpy(offsets), inverse)
    np.testing.assert_allclose(again.numpy(), per_vertex.numpy(), atol=1e-12)  # a projection


def test_the_second_targets_take_the_first_answers_error_and_keep_the_noise(movi_file):
    """An exact first answer leaves the recording's second targets (the noise that the first
    target keeps is kept); a first answer off by a rigid velocity error e asks the second step
    for −e more in both its position and velocity columns, and the gradient of the second step's
    loss reaches the first answer."""
    config = STAR
    scene = scenes_from_file(movi_file, config)[0]
    frame = _busiest_frame(scene, config) - 1
    settings = TrainingSettings()
    first, targets = training_example(config, scene, frame, torch.Generator().manual_seed(1), settings)
    (second,) = later_steps_of(config, scene, frame, first, 1.0, dataclasses.replace(settings, unroll=2))
    assert second.start.abs().max() > 1e-3  # frame t's noise, which the first target keeps
    simulator = LearnedSimulator(config)
    with torch.no_grad():
        simulator(first.graph, accumulate=True)
        simulator.normalized_targets(targets, accumulate=True)
    exact = simulator.normalized_targets(targets, accumulate=False)
    graph, second_targets = later_step_inputs(simulator, exact, targets, second)
    torch.testing.assert_close(second_targets, second.targets, atol=1e-6, rtol=0)

    error = torch.zeros_like(targets)
    error[:, 3:] = torch.tensor([0.004, -0.002, 0.001])  # every vertex, so every object: rigid
    off = simulator.normalized_targets(targets + error, accumulate=False).requires_grad_()
    graph, shifted = later_step_inputs(simulator, off, targets, second)
    change = (shifted - second.targets).detach()
    expected = torch.cat([-error[:, 3:], -error[:, 3:]], dim=1)
    torch.testing.assert_close(change, expected, atol=1e-6, rtol=0)
    loss = ((simulator(graph)[second.rows] - shifted) ** 2).mean()
    loss.backward()
    assert off.grad.abs().sum() > 0


def test_a_third_step_takes_the_second_answers_error(movi_file):
    """With three steps, exact answers leave the recording's third targets; a second answer off
    by a rigid velocity error e asks the third step for −e more in both columns, and the third
    step's loss has a gradient on the first answer, through the second step's graph."""
    config = STAR
    scene = scenes_from_file(movi_file, config)[0]
    frame = _busiest_frame(scene, config) - 1
    settings = TrainingSettings(unroll=3)
    first, targets = training_example(config, scene, frame, torch.Generator().manual_seed(1), settings)
    second, third = later_steps_of(config, scene, frame, first, 1.0, settings)
    torch.testing.assert_close(third.start, second.start, rtol=0, atol=0)  # the kept noise, carried
    simulator = LearnedSimulator(config)
    with torch.no_grad():
        simulator(first.graph, accumulate=True)
        simulator.normalized_targets(targets, accumulate=True)
    normalized = functools.partial(simulator.normalized_targets, accumulate=False)
    _, second_targets = later_step_inputs(simulator, normalized(targets), targets, second)
    _, third_targets = later_step_inputs(simulator, normalized(second_targets), second_targets, third)
    torch.testing.assert_close(third_targets, third.targets, atol=1e-6, rtol=0)

    error = torch.zeros_like(second_targets)
    error[:, 3:] = torch.tensor([-0.003, 0.001, 0.002])
    _, shifted = later_step_inputs(simulator, normalized(second_targets + error), second_targets, third)
    torch.testing.assert_close(shifted - third.targets, -error[:, [3, 4, 5, 3, 4, 5]], atol=1e-6, rtol=0)

    answer = normalized(targets).requires_grad_()
    graph, second_targets = later_step_inputs(simulator, answer, targets, second)
    second_answer = simulator(graph)[second.rows]
    graph, third_targets = later_step_inputs(simulator, second_answer, second_targets, third)
    loss = ((simulator(graph)[third.rows] - normalized(third_targets)) ** 2).mean()
    loss.backward()
    assert answer.grad.abs().sum() > 0


def test_examples_near_the_end_of_their_recording_take_the_steps_it_has(movi_file):
    """Later steps stop where the recording does, and a batch's step k reads the rows of its
    step k−1 that belong to the examples that have both."""
    config = STAR
    scene = scenes_from_file(movi_file, config)[0]
    last = scene.positions.shape[0] - 1
    settings = TrainingSettings(unroll=3)
    examples, chains = [], []
    for frame in (last - 2, 10, last - 1, 11):
        example = training_example(config, scene, frame, torch.Generator().manual_seed(frame), settings)
        examples.append(example)
        chains.append(later_steps_of(config, scene, frame, example[0], 1.0, settings))
    assert [len(chain) for chain in chains] == [1, 2, 0, 2]
    batch = batch_of(examples, later=chains)
    rows = len(examples[0][1])  # every example of one scene has the same dynamic vertices
    second, third = batch["later"]
    torch.testing.assert_close(second.first, torch.cat([torch.arange(rows) + rows * k for k in (0, 1, 3)]))
    torch.testing.assert_close(third.first, torch.cat([torch.arange(rows) + rows * k for k in (1, 2)]))
    torch.testing.assert_close(third.targets, torch.cat([chains[1][1].targets, chains[3][1].targets]))
    assert "later" not in batch_of(examples)
    assert batch_of(examples[2:3], later=chains[2:3])["later"] == []


@pytest.mark.parametrize("unroll", [2, 3])
def test_training_through_several_steps_fits_a_spinning_box_in_free_fall(tmp_path, unroll):
    data = write_trajectories(tmp_path / "drop.h5", box_drop_file(frames=12))
    settings = TrainingSettings(
        steps=200,
        batch_size=2,
        unroll=unroll,
        learning_rate_initial=3e-3,
        learning_rate_final=1e-3,
        normalizer_accumulation_steps=5,
        noise_translation_std=0.0,
        noise_rotation_std=0.0,
    )
    trainer = make_trainer(data, STAR, settings)
    trainer.run()
    losses = [entry["loss"] for entry in trainer.history]
    assert np.mean(losses[-20:]) < np.mean(losses[:20]) / 50


@pytest.mark.parametrize("unroll", [2, 3])
def test_training_through_several_steps_resumes_exactly(movi_file, tmp_path, unroll):
    settings = TrainingSettings(steps=8, batch_size=2, unroll=unroll, checkpoint_every=4)
    straight = make_trainer(movi_file, STAR, settings)
    straight.run()
    interrupted = make_trainer(movi_file, STAR, settings)
    interrupted.run(tmp_path / "half.pt", until_step=4)
    resumed = make_trainer(movi_file, STAR, TrainingSettings(steps=8), resume_from=tmp_path / "half.pt")
    resumed.run()
    for name, value in straight.simulator.state_dict().items():
        torch.testing.assert_close(resumed.simulator.state_dict()[name], value, rtol=0, atol=0)


@pytest.mark.parametrize(
    "config, message",
    [
        (simulator_config_for("fignet-star", "tiny", 0.2, max_faces=64), "velocity-state"),
        (dataclasses.replace(STAR, free_motion=True), "free-motion"),
    ],
    ids=["positions", "free-motion"],
)
def test_a_two_step_loss_is_refused_where_it_cannot_follow_the_model(movi_file, config, message):
    with pytest.raises(FignetError, match=message):
        make_trainer(movi_file, config, TrainingSettings(steps=1, unroll=2))


def test_a_two_step_loss_with_pushforward_is_refused(movi_file):
    with pytest.raises(FignetError, match="pushforward"):
        make_trainer(movi_file, STAR, TrainingSettings(steps=1, unroll=2, pushforward=1, batch_size=2))
