"""`frame_sampling`: which frames training draws, and the loss weights that keep the uniform
expectation when impact frames are drawn more often."""

import dataclasses

import numpy as np
import pytest
import torch

from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.scene_graph import GraphConfig
from fignetctl.core.model.simulator import SimulatorConfig
from fignetctl.core.model.training import (
    MOTION_RESOLUTION,
    MOTION_SHARE,
    FrameSampler,
    TrainingSettings,
    frame_motion,
    regression_loss,
)
from fignetctl.errors import FignetError
from tests.conftest import box_drop_file

CONFIG = SimulatorConfig(network=PRESETS["tiny"], graph=GraphConfig(0.1, False))
GRAVITY = (0.0, 0.0, -10.0)


def _scenes(*files):
    scenes = []
    for data in files:
        scenes += scenes_from_data(data, CONFIG, TRAINING_STATIC_REACH)
    return scenes


def _bouncing_box(frames=20, impact=7):
    """The box falls at 3 m/s plus free fall, bounces at frame `impact` and rises at 3 m/s less
    free fall: no change of motion beyond gravity but at the impact; no spin."""
    data = box_drop_file(frames=frames, spin=0.0, height=2.0)
    trajectory = data.trajectories["00000"]
    step = 3.0 * data.dt
    heights = 2.0 - step * np.abs(np.arange(frames) - impact)
    heights -= 0.5 * 10.0 * (np.arange(frames) * data.dt) ** 2  # so that x'' - g dt^2 is 0 off the impact
    positions = np.array(trajectory.positions)
    positions[:, 1, 2] = heights
    return dataclasses.replace(
        data, trajectories={"00000": dataclasses.replace(trajectory, positions=positions)}
    )


def test_motion_of_a_spinning_box_in_free_flight_is_its_corners_circular_second_difference():
    data = box_drop_file(frames=10, spin=3.0, height=2.0)
    (scene,) = _scenes(data)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    radii = np.linalg.norm(corners - np.outer(corners @ axis, axis), axis=1)  # distance from the spin axis
    angle = 3.0 * data.dt  # turned per frame
    expected = np.sqrt(np.mean((2 * radii * (1 - np.cos(angle))) ** 2))  # a chord's second difference
    expected -= MOTION_RESOLUTION
    motion = frame_motion(scene, GRAVITY)
    assert motion.shape == (8,)
    np.testing.assert_allclose(motion, expected, rtol=2e-3)


def test_uniform_sampling_makes_the_draws_training_always_made():
    scenes = _scenes(box_drop_file(frames=9), box_drop_file(frames=14))
    sampler = FrameSampler(scenes, "uniform")
    ours, theirs = np.random.default_rng(5), np.random.default_rng(5)
    for _ in range(200):
        scene = theirs.integers(len(scenes))  # the loop TrainingBatches had
        frame = int(theirs.integers(1, scenes[scene].positions.shape[0] - 1))
        assert sampler.draw(ours) == (scene, frame, 1.0)


def test_motion_sampling_draws_the_impact_more_and_its_weights_keep_the_uniform_expectation():
    scenes = _scenes(_bouncing_box(frames=20, impact=7), box_drop_file(frames=12, spin=0.0))
    motion = [frame_motion(scene, GRAVITY) for scene in scenes]
    assert np.argmax(motion[0]) == 6 and motion[0][6] > 100 * np.delete(motion[0], 6).max()  # frame t = 7
    sampler = FrameSampler(scenes, "motion", GRAVITY)
    rng, draws = np.random.default_rng(0), 40000
    counts, weighted = {}, {}
    for _ in range(draws):
        scene, frame, weight = sampler.draw(rng)
        assert 1 <= frame <= scenes[scene].positions.shape[0] - 2
        counts[scene, frame] = counts.get((scene, frame), 0) + 1
        weighted[scene, frame] = weighted.get((scene, frame), 0.0) + weight
    uniform = {(s, f): 1 / (2 * (len(m))) for s, m in enumerate(motion) for f in range(1, len(m) + 1)}
    impact = (1 - MOTION_SHARE) * uniform[0, 7] + MOTION_SHARE * motion[0][6] / sum(m.sum() for m in motion)
    assert counts[0, 7] / draws == pytest.approx(impact, abs=4 * np.sqrt(impact / draws))
    assert counts[0, 7] / draws > 8 * uniform[0, 7]
    for key, probability in uniform.items():  # weighted frequencies: the uniform distribution
        assert weighted.get(key, 0.0) / draws == pytest.approx(probability, abs=0.15 * probability), key


def test_motion_sampling_of_scenes_without_any_change_of_motion_is_uniform():
    scenes = _scenes(box_drop_file(frames=12, spin=0.0))  # free fall: no change beyond gravity
    sampler = FrameSampler(scenes, "motion", GRAVITY)
    np.testing.assert_allclose(sampler.weights, 1.0)
    with pytest.raises(FignetError, match="frame_sampling = 'impacts'"):
        FrameSampler(scenes, "impacts")
    with pytest.raises(FignetError, match="needs the data's gravity"):
        FrameSampler(scenes, "motion")


@pytest.mark.parametrize("loss", ["mse", "huber"])
def test_weighted_loss_weighs_each_node(loss):
    config = TrainingSettings(loss=loss)
    generator = torch.Generator().manual_seed(0)
    predictions, targets = torch.randn(6, 3, generator=generator) * 2, torch.randn(6, 3, generator=generator)
    plain = regression_loss(predictions, targets, config)
    assert regression_loss(predictions, targets, config, torch.ones(6)) == pytest.approx(float(plain))
    weights = torch.tensor([0.5, 2.0, 1.0, 0.0, 3.0, 1.5])
    per_node = [float(regression_loss(predictions[i : i + 1], targets[i : i + 1], config)) for i in range(6)]
    expected = sum(w * p for w, p in zip(weights.tolist(), per_node)) / 6
    assert float(regression_loss(predictions, targets, config, weights)) == pytest.approx(expected)
