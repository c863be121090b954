"""benchmarks/resting_box.py: the scene it builds, and what it reads off a rollout."""

import numpy as np
import pytest

from fignetctl.core.model.apply import load_model, rollout_trajectory
from fignetctl.core.transforms import transform_points
from tests.bench import load_benchmark

resting_box = load_benchmark("resting_box")


@pytest.mark.parametrize("size, gap, subdivisions, mass", [(2.0, 0.0, 0, 1.0), (1.0, 0.001, 2, 20.0)])
def test_the_box_rests_its_gap_above_the_floor_top(size, gap, subdivisions, mass):
    scene = resting_box.resting_box_scene(size, gap, subdivisions, mass)
    trajectory = scene.trajectories["scene"]
    np.testing.assert_array_equal(trajectory.static, [True, False])
    np.testing.assert_allclose(trajectory.mass[1], mass)
    assert len(scene.meshes["object"].faces) == 12 * 4**subdivisions
    floor, box = (
        transform_points(
            scene.meshes[name].vertices, 1.0, trajectory.positions[1, o], trajectory.quaternions[1, o]
        )
        for name, o in (("environment", 0), ("object", 1))
    )
    assert floor[:, 2].max() == pytest.approx(0.0, abs=1e-6)
    assert box[:, 2].min() == pytest.approx(gap, abs=1e-6)
    np.testing.assert_allclose(box.max(axis=0) - box.min(axis=0), size, atol=1e-6)
    np.testing.assert_array_equal(trajectory.positions[0], trajectory.positions[1])  # at rest
    assert not trajectory.velocities.any() and not trajectory.angular_velocities.any()


def test_measure_reads_the_first_steps_rise_and_the_largest_displacement():
    """The bundled model's rollout of the resting box, read back against the rollout itself."""
    simulator = load_model(None)
    scene = resting_box.resting_box_scene(2.0, 0.0, 0, 1.0)
    rise, largest = resting_box.measure(simulator, scene, 5, guards=False)
    positions = rollout_trajectory(simulator, scene, 5).trajectories["scene"].positions[1:, 1]
    assert rise == pytest.approx(positions[1, 2] - positions[0, 2], abs=1e-7)
    assert largest == pytest.approx(np.linalg.norm(positions - positions[0], axis=1).max(), abs=1e-7)
    assert largest >= abs(rise)
