"""Simulating a small scene at the model's size (Froude similarity), against the analytic answer."""

import dataclasses

import numpy as np
import pytest

from fignetctl.core.model import froude
from fignetctl.core.model.apply import load_model, rollout_trajectory
from fignetctl.core.model.simulator import SimulatorConfig, free_flight_poses
from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.core.transforms import quat_angle_deg, quat_from_axis_angle, quat_multiply
from fignetctl.errors import FignetError
from tests.conftest import box_drop_file

GRAVITY = np.array([0.0, 0.0, -10.0])
SPIN_AXIS = np.array([1.0, 2.0, 2.0]) / 3.0


class BallisticSimulator:
    """Exact free flight at a fixed frame time, in whatever units it is given: Verlet under
    GRAVITY and constant angular velocity. Records the largest dynamic side it was shown."""

    def __init__(self, dt):
        self.config = SimulatorConfig()
        self.dt = dt
        self.sides = []
        self.rotations = 1

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        return (*self.step(geometry, positions, quaternions, free_flight), None, None)

    def step(self, geometry, positions, quaternions, free_flight=None):
        dynamic = ~geometry.static
        rest = geometry.rest_vertices[np.isin(geometry.vertex_object, np.flatnonzero(dynamic))]
        self.sides.append(float((rest.max(axis=0) - rest.min(axis=0)).max()))
        flown = free_flight_poses(positions[:2], quaternions[:2], GRAVITY * self.dt**2)
        return (
            np.where(dynamic[:, None], flown[0], positions[2]),
            np.where(dynamic[:, None], flown[1], quaternions[2]),
        )


def small_throw(path, size=0.1, dt=1 / 30, spin=3.0, gravity=GRAVITY):
    """A `size` m box thrown sideways and spinning above a static floor, sampled from the exact
    motion; the file says its gravity is `gravity`."""
    data = dataclasses.replace(
        box_drop_file(frames=2, dt=dt, spin=spin, height=1.0), gravity=np.asarray(gravity)
    )
    trajectory = data.trajectories["00000"]
    positions = trajectory.positions.copy()
    positions[:, 1, 0] = 0.7 * np.arange(2) * dt
    trajectory = dataclasses.replace(
        trajectory, positions=positions, scales=np.array([1.0, size], np.float32)
    )
    write_trajectories(path, dataclasses.replace(data, trajectories={"00000": trajectory}))
    return trajectory


def exact_pose(trajectory, times, dt, spin=3.0, gravity=GRAVITY):
    """Position and quaternion of the box `times` seconds after frame 1 (the file's parabola
    under `gravity`, and its spin)."""
    start = trajectory.positions[1, 1].astype(np.float64)
    velocity = (trajectory.positions[1, 1] - trajectory.positions[0, 1]) / dt + 0.5 * gravity * dt
    positions = start + velocity * times[:, None] + 0.5 * gravity * times[:, None] ** 2
    turn = quat_from_axis_angle(np.broadcast_to(SPIN_AXIS, (len(times), 3)), spin * times)
    return positions, quat_multiply(turn, trajectory.quaternions[1, 1].astype(np.float64))


@pytest.mark.parametrize("scale", [1.0, 4.0, 21.0])
def test_a_scaled_rollout_is_the_real_motion_at_the_new_frame_time(tmp_path, scale):
    dt = 1 / 30
    trajectory = small_throw(tmp_path / "throw.h5", dt=dt)
    simulator = BallisticSimulator(dt)
    result = rollout_trajectory(simulator, read_trajectories(tmp_path / "throw.h5"), 12, sim_scale=scale)
    assert result.dt == pytest.approx(dt / np.sqrt(scale))
    rolled = result.trajectories["00000"]
    times = (np.arange(14) - 1) * result.dt
    positions, quaternions = exact_pose(trajectory, times, dt)
    np.testing.assert_allclose(rolled.positions[:, 1], positions, atol=2e-6)
    assert quat_angle_deg(rolled.quaternions[:, 1], quaternions).max() < 1e-3
    np.testing.assert_array_equal(rolled.positions[:, 0], trajectory.positions[:1, 0].repeat(14, axis=0))
    assert simulator.sides[0] == pytest.approx(0.1 * scale, rel=1e-6)  # the model saw the scaled box


@pytest.mark.parametrize("scale", [1.0, 4.0])
@pytest.mark.parametrize("strength", [1.62, 9.81, 25.0])
def test_a_scene_under_another_gravity_is_simulated_under_the_models_in_its_time(tmp_path, scale, strength):
    """A model that learned g = 10 m/s² (it steps exact free flight under it) gives a box under
    g' the motion under g', at frames dt / √(s·g'/g) apart."""
    dt, gravity = 1 / 30, np.array([0.0, 0.0, -strength])
    trajectory = small_throw(tmp_path / "throw.h5", dt=dt, gravity=gravity)
    simulator = BallisticSimulator(dt)
    simulator.config = SimulatorConfig(gravity=tuple(GRAVITY))
    result = rollout_trajectory(simulator, read_trajectories(tmp_path / "throw.h5"), 12, sim_scale=scale)
    assert result.dt == pytest.approx(dt / np.sqrt(scale * strength / 10.0))
    np.testing.assert_array_equal(result.gravity, gravity)
    rolled = result.trajectories["00000"]
    times = (np.arange(14) - 1) * result.dt
    positions, quaternions = exact_pose(trajectory, times, dt, gravity=gravity)
    np.testing.assert_allclose(rolled.positions[:, 1], positions, atol=2e-6)
    assert quat_angle_deg(rolled.quaternions[:, 1], quaternions).max() < 1e-3


@pytest.mark.parametrize(
    "gravity, message",
    [
        (
            [0.0, -9.81, 0.0],
            "its gravity points along .0, -1, 0.. 90° from the model's .0, 0, -10. m/s²; rotate",
        ),
        ([0.0, 0.0, 0.0], "has no gravity, and the model learned to simulate under .0, 0, -10. m/s²"),
    ],
)
def test_a_scene_whose_gravity_cannot_be_mapped_is_refused(tmp_path, gravity, message):
    small_throw(tmp_path / "throw.h5", gravity=gravity)
    simulator = BallisticSimulator(1 / 30)
    simulator.config = SimulatorConfig(gravity=tuple(GRAVITY))
    with pytest.raises(FignetError, match=f"^scene: {message}"):
        rollout_trajectory(simulator, read_trajectories(tmp_path / "throw.h5"), 2)
    assert froude.gravity_ratio([0.0, 0.0, -10.005], GRAVITY) == 1.0  # within 1e-3: the model's
    assert froude.gravity_ratio(gravity, None) == 1.0  # a model that records none takes the file's


def test_evaluate_refuses_data_under_another_gravity(tmp_path):
    from fignetctl.core.model.apply import evaluate_trajectories

    small_throw(tmp_path / "throw.h5", gravity=[0.0, 0.0, -9.81])
    simulator = BallisticSimulator(1 / 30)
    simulator.config = SimulatorConfig(gravity=tuple(GRAVITY))
    with pytest.raises(FignetError, match="gravity is 9.81 m/s², the model learned 10 m/s²"):
        evaluate_trajectories(simulator, read_trajectories(tmp_path / "throw.h5"))


def test_auto_brings_the_largest_moving_object_to_the_training_size(tmp_path):
    small_throw(tmp_path / "throw.h5", size=0.12)
    simulator = BallisticSimulator(1 / 30)
    result = rollout_trajectory(simulator, read_trajectories(tmp_path / "throw.h5"), 3, sim_scale="auto")
    assert simulator.sides[0] == pytest.approx(froude.TRAINING_OBJECT_SIDE, rel=1e-6)
    assert result.attrs["sim_scale"] == pytest.approx(froude.TRAINING_OBJECT_SIDE / 0.12)


def test_auto_leaves_a_scene_of_the_training_size_as_it_is(tmp_path):
    low, high = froude.TRAINING_SIDE_RANGE  # the box's side is its scale
    inside, outside = (low + 0.01, high - 0.01, 2.0), (low - 0.01, high + 0.01, 0.12)
    for size, expected in [(s, 1.0) for s in inside] + [
        (s, froude.TRAINING_OBJECT_SIDE / s) for s in outside
    ]:
        small_throw(tmp_path / f"throw-{size}.h5", size=size)
        data = read_trajectories(tmp_path / f"throw-{size}.h5")
        assert froude.auto_scale(data, "00000") == pytest.approx(expected, rel=1e-6)


def test_auto_uses_the_sizes_a_model_file_records(tmp_path):
    small_throw(tmp_path / "throw.h5", size=0.12)
    data = read_trajectories(tmp_path / "throw.h5")
    trained = {"dynamic": {"mass": [1, 1], "largest_side": [0.1, 0.15, 0.2]}}
    assert froude.auto_scale(data, "00000", trained) == 1.0
    trained["dynamic"]["largest_side"] = [0.5, 0.6, 0.8]
    assert froude.auto_scale(data, "00000", trained) == pytest.approx(0.6 / 0.12)


def test_the_rollout_command_scales_a_small_scene_by_default_and_says_so(tmp_path):
    from click.testing import CliRunner

    from fignetctl.cli import cli

    small_throw(tmp_path / "throw.h5", size=0.12)
    result = CliRunner().invoke(
        cli, ["rollout", str(tmp_path / "throw.h5"), "--steps", "2", "-o", str(tmp_path / "r.h5")]
    )
    assert result.exit_code == 0, result.output
    # the bundled model records the sizes it trained on: a 12 cm box, smaller, is scaled to their median
    low, median, high = load_model().trained_properties["dynamic"]["largest_side"]
    assert not low <= 0.12 <= high
    expected = median / 0.12
    assert f"simulated at {expected:.4g}x its size" in result.output
    assert read_trajectories(tmp_path / "r.h5").attrs["sim_scale"] == pytest.approx(expected)


def test_the_rollout_command_maps_a_scene_under_another_gravity_and_says_so(tmp_path):
    from click.testing import CliRunner

    from fignetctl.cli import cli

    small_throw(tmp_path / "throw.h5", size=2.0, gravity=[0.0, 0.0, -9.81])  # of the training size
    result = CliRunner().invoke(
        cli, ["rollout", str(tmp_path / "throw.h5"), "--steps", "2", "-o", str(tmp_path / "r.h5")]
    )
    assert result.exit_code == 0, result.output
    assert (
        "under the gravity the model learned (10 m/s²) in the time that makes it the scene's (9.81 m/s²)"
        in (result.output)
    )
    rolled = read_trajectories(tmp_path / "r.h5")
    assert rolled.dt == pytest.approx((1 / 30) / np.sqrt(0.981)) and rolled.attrs[
        "gravity_ratio"
    ] == pytest.approx(0.981)
    np.testing.assert_allclose(rolled.gravity, [0.0, 0.0, -9.81])


def test_a_moving_static_object_cannot_be_rescaled(tmp_path):
    data = box_drop_file(frames=2)
    trajectory = data.trajectories["00000"]
    positions = trajectory.positions.copy()
    positions[1, 0, 0] += 0.01  # the floor slides
    data = dataclasses.replace(
        data, trajectories={"00000": dataclasses.replace(trajectory, positions=positions)}
    )
    with pytest.raises(FignetError, match="static object 0 moves"):
        froude.scaled_scene(data, "00000", 4.0)


def test_the_rollout_command_takes_auto_and_refuses_nonsense(tmp_path):
    from click.testing import CliRunner

    from fignetctl.cli import cli

    small_throw(tmp_path / "throw.h5")
    result = CliRunner().invoke(
        cli, ["rollout", str(tmp_path / "throw.h5"), "--sim-scale", "-2", "-o", str(tmp_path / "r.h5")]
    )
    assert result.exit_code != 0 and "is not 'auto' or a scale between 0.001 and 1000" in result.output
    assert not (tmp_path / "r.h5").exists()
