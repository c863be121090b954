"""benchmarks/long_rollout.py: the floor depths and drifts it reports, of the rollout and of the recording."""

import itertools

import numpy as np

from fignetctl.core.model.rollout import guards_for
from fignetctl.core.model.scene_data import scene_from_trajectory
from fignetctl.core.model.simulator import SimulatorConfig
from fignetctl.core.transforms import quat_to_matrix
from tests.bench import load_benchmark
from tests.conftest import box_drop_file
from tests.core.model.test_free_flight import untrained_simulator

long_rollout = load_benchmark("long_rollout")


def test_the_recorded_depth_is_the_deepest_corner_of_the_recorded_box_below_the_floor():
    """A unit box recorded falling through the floor (z = 0): the depth of the recording over
    the rolled-out frames is the lowest of its 8 corners, computed here from the poses."""
    data = box_drop_file(frames=30, dt=1 / 30, height=0.9)
    scene = scene_from_trajectory(data, "00000", SimulatorConfig())
    simulator = untrained_simulator(scene)
    guards = guards_for(data.dt, data.gravity, False, False, False)
    row = long_rollout.one_trajectory(simulator, scene, 12, guards=guards)
    trajectory = data.trajectories["00000"]
    corners = np.array(list(itertools.product((-0.5, 0.5), repeat=3)))
    lowest = min(
        (corners @ quat_to_matrix(trajectory.quaternions[t, 1].astype(float)).T)[:, 2].min()
        + trajectory.positions[t, 1, 2]
        for t in range(row["frames"])
    )
    assert row["frames"] == 14 == row["recorded_frames"]
    assert lowest < -0.1  # the recording went through the floor within the frames
    np.testing.assert_allclose(row["recorded_max_penetration_m"], -lowest, atol=1e-5)
    assert np.isfinite(row["max_penetration_m"]) and row["max_penetration_m"] >= 0


def test_the_recorded_drift_is_the_recording_s_own_motion_over_the_rollout_s_last_frames():
    """A box recorded falling for 30 frames: over a 12-step rollout's last 14 frames (all of
    them, shorter than the 50-frame window) the recording moves it by its own fall; a 40-step
    rollout outlasts the recording and reports no recorded drift."""
    data = box_drop_file(frames=30, dt=1 / 30, height=0.9)
    scene = scene_from_trajectory(data, "00000", SimulatorConfig())
    simulator = untrained_simulator(scene)
    guards = guards_for(data.dt, data.gravity, False, False, False)
    row = long_rollout.one_trajectory(simulator, scene, 12, guards=guards)
    recorded = data.trajectories["00000"].positions[:, 1]
    expected = np.linalg.norm(recorded[13] - recorded[0])
    assert expected > 0.1
    np.testing.assert_allclose(row["recorded_drift_last_50_steps_m"], [expected], atol=1e-4)
    assert "recorded_drift_last_50_steps_m" not in long_rollout.one_trajectory(
        simulator, scene, 40, guards=guards
    )


def test_the_deepest_object_s_depth_is_split_by_how_fast_it_came_into_each_step_that_took_it_deeper():
    """Object 1 starts 1 mm deep, falls at 3 m/s and goes 4 cm into the floor in one step,
    bounces up at 0.2 m/s to 2 cm, then sinks 4 mm a step at 0.04 m/s to 4.4 cm: 1 mm at the
    start, 3.9 cm fast and, of the slow sinking, only the 4 mm below the 4 cm it had reached.
    Object 0 never goes as deep."""
    dt = 0.1
    z = np.array([1.0, 0.7, 0.4, 0.1, 0.12, 0.116, 0.112, 0.108, 0.104, 0.100, 0.096])
    positions = np.zeros((len(z), 2, 3))
    positions[:, 1, 2] = z
    depths = np.zeros((len(z), 2))
    depths[:3, 1] = 0.001
    depths[3:, 1] = 0.14 - z[3:]
    depths[:, 0] = 0.03
    row = long_rollout.depth_by_speed(depths, positions, dt)
    assert row["object"] == 1 and row["frame"] == 10
    np.testing.assert_allclose(row["depth_m"], 0.044)
    split = row["depth_by_entry_speed_m"]
    assert list(split) == ["at the start", "0-0.1 m/s", "0.1-0.5 m/s", "0.5-2 m/s", "2-inf m/s"]
    np.testing.assert_allclose(list(split.values()), [0.001, 0.004, 0.0, 0.0, 0.039], atol=1e-9)
    np.testing.assert_allclose(sum(split.values()), row["depth_m"])
