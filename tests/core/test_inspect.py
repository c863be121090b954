import numpy as np
import pytest

from fignetctl.core.inspect import angular_velocities, energies, lowest_vertex_heights, summarize
from tests.conftest import box_drop_file


def test_free_fall_with_spin_conserves_energy():
    data = box_drop_file(frames=30, spin=4.0, height=5.0)
    trajectory = data.trajectories["00000"]
    energy = energies(data, trajectory)
    assert energy["kinetic_rotational"].min() > 0.1  # the box really spins
    total = energy["total"]
    assert np.ptp(total) < 1e-3 * np.abs(total).max()


def test_constant_spin_is_measured_exactly():
    data = box_drop_file(frames=8, spin=4.0)
    omega = angular_velocities(data.trajectories["00000"].quaternions, data.dt)
    np.testing.assert_allclose(np.linalg.norm(omega[:, 1], axis=1), 4.0, rtol=1e-4)
    np.testing.assert_allclose(omega[:, 0], 0.0)


def test_summary_counts_and_lowest_vertex():
    data = box_drop_file(frames=5, spin=0.0, height=2.0)
    summary = summarize(data)
    assert (summary["trajectories"], summary["frames"], summary["objects"]) == (1, 5, 2)
    lowest = lowest_vertex_heights(data, data.trajectories["00000"])
    assert lowest[0] == pytest.approx(1.5)  # a unit box centred at 2 m
