"""`SceneStore`: training's scenes made when drawn, a bounded number kept, the same examples
whatever it keeps."""

import dataclasses
import pickle

import numpy as np
import pytest
import torch

from fignetctl.core.model.scene_data import (
    TRAINING_STATIC_REACH,
    SceneStore,
    frame_counts,
    property_inputs,
    scenes_from_data,
)
from fignetctl.core.model.training import (
    TrainingBatches,
    TrainingSettings,
    make_trainer,
    simulator_config_for,
)
from fignetctl.core.trajectory import write_trajectories
from tests.conftest import box_drop_file

CONFIG = dataclasses.replace(
    simulator_config_for("fignet-star", "tiny", 0.3, state="velocities"), gravity=(0.0, 0.0, -10.0), dt=1 / 60
)


def _file(count=5):
    """`count` boxes of different sizes and masses dropped from different heights with different
    spins, 6 to 10 frames long."""
    trajectories, meshes = {}, None
    for k in range(count):
        data = box_drop_file(frames=6 + k, spin=1.0 + k, height=0.3 + 0.1 * k)
        trajectory = data.trajectories["00000"]
        scales = np.array([1.0, 0.6 + 0.1 * k], np.float32)
        trajectories[f"{k:05d}"] = dataclasses.replace(
            trajectory, scales=scales, mass=trajectory.mass * (1 + k)
        )
        meshes = data.meshes
    return dataclasses.replace(data, meshes=meshes, trajectories=trajectories)


def _equal(actual, expected):
    torch.testing.assert_close(actual, expected, rtol=0, atol=0)


def _same_scene(first, second):
    for field in ("positions", "quaternions", "velocities", "angular_velocities"):
        np.testing.assert_array_equal(getattr(first, field), getattr(second, field))
    for field in ("rest_vertices", "faces", "vertex_object", "static", "properties", "surface_edges"):
        np.testing.assert_array_equal(getattr(first.geometry, field), getattr(second.geometry, field))
    assert (first.name, first.dt) == (second.name, second.dt)


def test_a_store_gives_the_scenes_of_the_file_and_keeps_at_most_its_capacity():
    data = _file()
    made = scenes_from_data(data, CONFIG, TRAINING_STATIC_REACH)
    store = SceneStore(data, CONFIG, TRAINING_STATIC_REACH, capacity=2)
    assert len(store) == 5 and frame_counts(store) == frame_counts(made) == [6, 7, 8, 9, 10]
    for index in (0, 3, 1, 3, 4, 0, -1, 2):
        _same_scene(store[index], made[index])
        assert len(store._scenes) <= 2
    assert list(store._scenes) == [4, 2]  # the last two drawn (-1 is 4)
    kept = store[2]
    assert store[2] is kept  # a kept scene is not made again, so its graph caches stay
    with pytest.raises(IndexError):
        store[5]
    assert [scene.name for scene in store] == list(data.trajectories)  # iterates as a list


def test_a_store_without_a_capacity_keeps_every_scene_and_pickles_without_them():
    store = SceneStore(_file(), CONFIG, TRAINING_STATIC_REACH)
    assert all(store[k] is store[k] for k in range(5)) and len(store._scenes) == 5
    copy = pickle.loads(pickle.dumps(store))
    assert len(copy._scenes) == 0 and len(copy) == 5
    _same_scene(copy[3], store[3])
    with pytest.raises(ValueError, match="capacity"):
        SceneStore(_file(), CONFIG, capacity=0)


def test_a_store_reads_the_trained_ranges_inputs_from_the_arrays_as_its_scenes_give_them():
    data = _file()
    store = SceneStore(data, CONFIG, TRAINING_STATIC_REACH, capacity=1)
    (pairs, sides), (made_pairs, made_sides) = (
        property_inputs(store),
        property_inputs(scenes_from_data(data, CONFIG)),
    )
    assert len(store._scenes) == 0  # no Scene made
    assert len(sides) == len(made_sides) == 5 and len({float(s[0]) for s in sides}) == 5
    for (properties, static), (made_properties, made_static), side, made_side in zip(
        pairs, made_pairs, sides, made_sides
    ):
        np.testing.assert_array_equal(properties, made_properties)
        np.testing.assert_array_equal(static, made_static)
        np.testing.assert_array_equal(side, made_side)


def test_training_batches_are_the_same_whatever_the_store_keeps():
    data = _file()
    settings = TrainingSettings(batch_size=3, seed=5, frame_sampling="motion")
    listed = TrainingBatches(scenes_from_data(data, CONFIG, TRAINING_STATIC_REACH), CONFIG, settings)
    stored = TrainingBatches(SceneStore(data, CONFIG, TRAINING_STATIC_REACH, capacity=1), CONFIG, settings)
    for step in range(8):
        first, second = listed[step], stored[step]
        for key in ("rows", "targets", "weights"):
            _equal(second[key], first[key])
        _equal(second["graph"].node_features, first["graph"].node_features)
        assert second["graph"].edge_sets.keys() == first["graph"].edge_sets.keys()
        for name, edges in first["graph"].edge_sets.items():
            for field in ("features", "senders", "receivers"):
                _equal(getattr(second["graph"].edge_sets[name], field), getattr(edges, field))


def test_a_run_with_one_scene_kept_trains_the_same_weights_as_one_that_keeps_all(tmp_path):
    path = write_trajectories(tmp_path / "drops.h5", _file())
    settings = TrainingSettings(steps=4, batch_size=3, pushforward=1, normalizer_accumulation_steps=2)
    kept = make_trainer(path, CONFIG, settings, scene_cache=None)
    dropped = make_trainer(path, CONFIG, settings, scene_cache=1)
    assert kept.simulator.trained_properties == dropped.simulator.trained_properties
    kept.run()
    dropped.run()
    assert len(dropped.scenes._scenes) == 1 and len(kept.scenes._scenes) == 5
    for name, value in kept.simulator.state_dict().items():
        _equal(dropped.simulator.state_dict()[name], value)
