"""benchmarks/learnability.py --model: a model file, trained elsewhere (`fignetctl train`),
is measured on the trajectories as the one trained in the benchmark would be."""

import torch

from fignetctl.core.model.checkpoint import save_checkpoint
from fignetctl.core.model.learnability import (
    CUBE_CASES,
    cube_trajectories,
    fraction_unexplained,
    one_step_examples,
    overfit,
    rigid_fraction_unexplained,
)
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.training import simulator_config_for
from tests.bench import load_benchmark

learnability = load_benchmark("learnability")


def test_a_model_file_measures_as_the_model_it_holds(tmp_path):
    torch.set_num_threads(1)
    data = cube_trajectories(*CUBE_CASES["dropped"])
    config = simulator_config_for("fignet-star", "tiny", 0.2, state="velocities", static_receivers=False)
    scenes = scenes_from_data(data, config, TRAINING_STATIC_REACH)
    trained = overfit(config, scenes, steps=60, batch_size=4, learning_rate=(3e-3, 3e-4)).simulator.eval()
    expected = fraction_unexplained(trained, one_step_examples(trained, scenes))
    expected_rigid = rigid_fraction_unexplained(trained, scenes)
    path = save_checkpoint(tmp_path / "model.pt", trained)

    simulator, measured_scenes, fvu, rigid = learnability.measure_model(path, data)

    assert not simulator.training and len(measured_scenes) == len(scenes)
    assert 0 < fvu["all"] < 1.5
    for key in ("all", "position", "velocity"):
        assert abs(fvu[key] - expected[key]) < 1e-6 * max(1.0, expected[key])
    assert abs(rigid["all"] - expected_rigid["all"]) < 1e-6
