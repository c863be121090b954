"""Physics ceilings: PyBullet restarted every frame from the finite-difference or velocity state.

Scenes are made here as make-dataset makes them (movi.generate, then the file written and read
back, so frames are float32 as in real files), from trimesh stand-in shapes: a cube, an
icosphere and an L of two boxes (whose principal frame is not the object frame).
"""

import dataclasses

import numpy as np
import pytest

from fignetctl.core import ceilings, movi
from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.core.transforms import (
    quat_angle_deg,
    quat_from_rotation_vector,
    quat_multiply,
    random_quaternions,
)
from fignetctl.errors import FignetError
from tests.core.stand_in_shapes import shape, stand_in_shapes

GRAVITY = 10.0
# Frame 2 from frame 1 stored as float32: positions (|x| < 8 m) carry up to half a float32 ulp
# (4.8e-7 m) in the start and again in the stored truth; measured up to 2.1e-7 m.
FLOAT32_POSITION_TOLERANCE = 5e-7


@pytest.fixture(scope="module")
def shapes():
    return stand_in_shapes()


def dataset(folder, shapes, seed, count, **overrides):
    """A make-dataset style file of `count` scenes, written and read back."""
    settings = dict(duration=1.0, num_objects=(3, 4))
    settings.update(overrides)
    config = movi.movi_config("movi-b", **settings)
    results = list(movi.generate(shapes, config, seed, range(count)))
    attrs = {"source": "fignetctl make-dataset", "config": config.to_json()}
    data = movi.dataset_file(results, shapes, config, count, attrs)
    return read_trajectories(write_trajectories(folder / f"d{seed}.h5", data))


@pytest.fixture(scope="module")
def tosses(tmp_path_factory, shapes):
    """Two 1 s scenes of 3-4 tossed cubes, balls and Ls (30 fps, 31 frames)."""
    return dataset(tmp_path_factory.mktemp("ceilings"), shapes, 5, 2)


@pytest.fixture(scope="module")
def spinning_fall(tmp_path_factory, shapes):
    """One ball falling freely from 20 m for 1 s, given a spin ω about a slanted axis at frame 1.

    The ball's inertia is isotropic, so it spins at constant ω: frame 1 + k is turned by
    exp(ω k dt) from frame 1. Returns the file and the expected quaternions of frames 1.. (30, 4).
    """
    config = dict(num_objects=(1, 1), spawn_region=((-1.0, -1.0, 20.0), (1.0, 1.0, 22.0)))
    data = dataset(tmp_path_factory.mktemp("fall"), [shapes[1]], 4, 1, **config)
    trajectory = data.trajectories["00000"]
    omega = np.array([1.0, -2.0, 3.0])
    q0 = random_quaternions(np.random.default_rng(0), 1)[0]
    q1 = quat_multiply(quat_from_rotation_vector(omega * data.dt), q0)
    trajectory.quaternions[0, 1], trajectory.quaternions[1, 1], trajectory.angular_velocities[1, 1] = (
        q0,
        q1,
        omega,
    )
    steps = np.arange(trajectory.num_frames - 1)[:, None]
    return data, quat_multiply(
        quat_from_rotation_vector(omega * data.dt * steps), trajectory.quaternions[1, 1]
    )


# ----------------------------------------------------------------------------- the restarts


def test_one_velocity_restart_reproduces_the_recorded_next_frame(tosses, shapes):
    """The same physics from the same state (no object touches another in frames 1-2 here)."""
    for key, truth in tosses.trajectories.items():
        positions, quaternions = ceilings.ceiling_rollout(tosses, key, "velocity", 1, assets=shapes)
        assert positions.shape == (3, truth.num_objects, 3) and quaternions.shape == (3, truth.num_objects, 4)
        assert positions.dtype == quaternions.dtype == np.float64
        np.testing.assert_array_equal(positions[:2], truth.positions[:2])
        np.testing.assert_array_equal(quaternions[:2], truth.quaternions[:2])
        np.testing.assert_allclose(positions[2], truth.positions[2], rtol=0, atol=FLOAT32_POSITION_TOLERANCE)
        assert quat_angle_deg(truth.quaternions[2], quaternions[2]).max() < 1e-4  # measured 4e-6 degrees
        assert not np.array_equal(truth.positions[2, 1:], truth.positions[1, 1:])  # they did move


def test_one_frame_from_a_given_state_is_the_restarted_rollouts_step(tosses, shapes):
    """`frame` from frame 1's recorded state is the velocity restart's frame 2; the floor's row
    comes back as given, whatever it held."""
    key = "00000"
    truth = tosses.trajectories[key]
    expected = ceilings.ceiling_rollout(tosses, key, "velocity", 1, assets=shapes)
    given = [np.array(values[1], np.float64) for values in (truth.positions, truth.quaternions)]
    given[0][0] = [7.0, 7.0, 7.0]
    velocities = [np.array(values[1], np.float64) for values in (truth.velocities, truth.angular_velocities)]
    with ceilings.RestartedPyBullet(tosses, shapes) as physics:
        positions, quaternions, linear, angular = physics.frame(key, *given, *velocities)
    np.testing.assert_array_equal(positions[1:], expected[0][2, 1:])
    np.testing.assert_array_equal(quaternions[1:], expected[1][2, 1:])
    np.testing.assert_array_equal(positions[0], [7.0, 7.0, 7.0])
    np.testing.assert_allclose(linear[1:], truth.velocities[2, 1:], rtol=0, atol=1e-4)
    assert linear.shape == angular.shape == (truth.num_objects, 3)


def test_restarts_keep_the_floor_where_it_is(tosses, shapes):
    key = "00000"
    for state in ceilings.STATES:
        positions, quaternions = ceilings.ceiling_rollout(tosses, key, state, 5, assets=shapes)
        assert positions.shape[0] == 7
        np.testing.assert_array_equal(
            positions[:, 0], np.repeat(tosses.trajectories[key].positions[1:2, 0], 7, 0)
        )
        np.testing.assert_array_equal(
            quaternions[:, 0], np.repeat(tosses.trajectories[key].quaternions[1:2, 0], 7, 0)
        )


def test_in_free_fall_the_velocity_state_is_exact_and_finite_differences_lag_behind(spinning_fall, shapes):
    """Finite differences over a frame of s physics steps (h = dt / s, symplectic Euler) give the
    frame's mean velocity, s(s+1)/2 g h² / (s h) short of the last: each restarted frame then
    falls s(s-1)/2 g h² less than PyBullet's, and after k steps the body is higher by
    s(s-1)/2 g h² k(k+1)/2 (2.11 m after 1 s at 30 fps). A constant spin is differenced exactly."""
    data, spun = spinning_fall
    truth = data.trajectories["00000"]
    steps = np.arange(truth.num_frames - 1)
    s, h = 8, data.dt / 8
    lag = s * (s - 1) / 2 * GRAVITY * h * h * steps * (steps + 1) / 2
    for state, expected_lag in (("velocity", 0.0 * lag), ("finite-difference", lag)):
        steps = truth.num_frames - 2
        positions, quaternions = ceilings.ceiling_rollout(data, "00000", state, steps, assets=[shapes[1]])
        error = positions[1:, 1] - truth.positions[1:, 1]
        np.testing.assert_allclose(error[:, :2], 0.0, atol=1e-6)  # measured 2.5e-7 m
        np.testing.assert_allclose(error[:, 2], expected_lag, rtol=0, atol=1e-4)  # measured 1.2e-5 m
        assert quat_angle_deg(spun, quaternions[1:, 1]).max() < 2e-4  # measured 2.8e-5 degrees


def test_finite_differences_do_worse_than_velocities_at_every_horizon(tosses, shapes):
    result = ceilings.evaluate_ceilings(tosses, assets=shapes)
    assert result["horizons"] == [3, 6, 10, 15]  # 0.1, 0.2, 0.33, 0.5 s; 1 s, 1.67 s and 50 steps do not fit
    objects = sum(t.num_objects - 1 for t in tosses.trajectories.values())
    assert result["trajectories"] == 2 and result["objects"] == objects and not result["keep_world"]
    finite, velocity = result["states"]["finite-difference"], result["states"]["velocity"]
    for fd_row, velocity_row in zip(finite, velocity):
        assert fd_row["steps"] == velocity_row["steps"] and fd_row["objects"] == objects
        assert fd_row["translation_rmse_m"] > 10 * velocity_row["translation_rmse_m"]
        assert velocity_row["rotation_rms_deg"] >= velocity_row["rotation_mean_deg"]
    assert finite[-1]["seconds"] == pytest.approx(0.5)


def test_the_summary_follows_the_metrics_definitions():
    summary = ceilings.error_summary([3.0, 4.0], [10.0, 20.0])
    assert summary["translation_rmse_m"] == pytest.approx(np.sqrt(12.5))
    assert summary["rotation_mean_deg"] == pytest.approx(15.0)
    assert summary["rotation_rms_deg"] == pytest.approx(np.sqrt(250.0))
    assert summary["objects"] == 2
    assert ceilings.horizon_steps(1 / 30, 121) == [3, 6, 10, 15, 30, 50]
    assert ceilings.horizon_steps(1 / 60, 121) == [6, 12, 20, 30, 50, 60, 100]


def continued_pybullet(data, key, shapes, num_steps):
    """(K, N, 3) positions of the dynamic objects when PyBullet simply runs on from frame 1."""
    truth = data.trajectories[key]
    with ceilings.RestartedPyBullet(data, shapes) as physics:
        simulator = physics.simulator
        specs = ceilings.object_specs(truth, physics.config, physics.asset_index, simulator)
        bodies = simulator.build_scene(specs)
        start = (truth.positions, truth.quaternions, truth.velocities, truth.angular_velocities)
        simulator.set_object_states(bodies, specs, *(np.asarray(field[1, 1:], np.float64) for field in start))
        positions = []
        for _ in range(num_steps):
            simulator.step_frame()
            positions.append(simulator.object_states(bodies, specs)[0])
    return np.stack(positions)


def test_only_a_fresh_world_forgets_the_contacts_of_earlier_frames(tosses, shapes):
    """Kept world: the velocity resets are no-ops, the rollout is PyBullet run on from frame 1
    (measured 5e-11 m). Fresh worlds: once objects land, PyBullet's contact manifolds (points
    gathered over several steps) are rebuilt every frame and the rollout departs from it (here
    by 2 cm and 29 cm within 1 s)."""
    for key, truth in tosses.trajectories.items():
        steps = truth.num_frames - 2
        continued = continued_pybullet(tosses, key, shapes, steps)
        kept, _ = ceilings.ceiling_rollout(tosses, key, "velocity", steps, assets=shapes, keep_world=True)
        fresh, _ = ceilings.ceiling_rollout(tosses, key, "velocity", steps, assets=shapes)
        np.testing.assert_allclose(kept[2:, 1:], continued, rtol=0, atol=1e-9)
        np.testing.assert_allclose(fresh[2:6, 1:], continued[:4], rtol=0, atol=1e-12)  # in the air
        assert np.abs(fresh[-1, 1:] - continued[-1]).max() > 0.01


# ----------------------------------------------------------------------------- in evaluate


def test_evaluate_measures_the_ceilings_beside_the_model(tosses, shapes):
    """The ceilings are methods of evaluate_scenes: metrics, curves and comparisons."""
    import torch

    from fignetctl.core.model.evaluation import evaluate_scenes
    from fignetctl.core.model.scene_data import scene_from_trajectory
    from fignetctl.core.model.scene_graph import build_scene_graph
    from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig
    from fignetctl.core.model.training import simulator_config_for

    torch.manual_seed(0)
    config = simulator_config_for("fignet-star", "tiny", 0.5, state="velocities")
    simulator = LearnedSimulator(
        dataclasses.replace(config, dt=tosses.dt, gravity=tuple(tosses.gravity))
    ).eval()
    scenes = [scene_from_trajectory(tosses, key, SimulatorConfig()) for key in tosses.trajectories]
    scene = scenes[0]  # normalizers from one frame; the weights stay random
    velocities = (scene.velocities[1] * scene.dt, scene.angular_velocities[1] * scene.dt)
    simulator(
        build_scene_graph(
            scene.geometry, scene.positions, scene.quaternions, simulator.config.graph, velocities
        ).graph,
        accumulate=True,
    )
    simulator.inverse_postprocess(
        np.ones((4, 3)), np.zeros((4, 3)), np.ones((4, 3)), np.ones((4, 3)), accumulate=True
    )
    with ceilings.RestartedPyBullet(tosses, shapes) as physics:
        references = {
            f"ceiling_{state}": (lambda scene, k, state=state: physics.rollout(scene.name, state, k))
            for state in ("velocity", "finite-difference")
        }
        report = evaluate_scenes(simulator, tosses, scenes, references=references)
    metrics = report["metrics"]
    assert set(metrics) == {
        "model",
        "constant_velocity",
        "stand_still",
        "ceiling_velocity",
        "ceiling_finite-difference",
    }
    first = metrics["ceiling_velocity"]["0.1_seconds"]["all"]
    assert first["translation_rmse_m"] < 1e-3 and first["objects"] == sum(
        (~t.static).sum() for t in tosses.trajectories.values()
    )
    for horizon in metrics["model"]:
        velocity, finite = (
            metrics[f"ceiling_{s}"][horizon]["all"]["translation_rmse_m"]
            for s in ("velocity", "finite-difference")
        )
        assert velocity < finite
    assert set(report["comparison"]) == set(metrics) - {"model"}
    assert len(report["curves"]["ceiling_velocity"]["step"]) == len(report["curves"]["model"]["step"])


# ----------------------------------------------------------------------------- nudged free runs


def test_a_nudged_free_fall_is_the_recording_moved_by_the_nudge(spinning_fall, shapes):
    """In free fall nothing depends on where the body is: the free run from frame 1 moved by a
    nudge stays that far from the recording at every frame, and without one replays it."""
    data, spun = spinning_fall
    truth = data.trajectories["00000"]
    steps = truth.num_frames - 2
    with ceilings.RestartedPyBullet(data, [shapes[1]]) as physics:
        for nudge in (0.0, 1e-3):
            positions, quaternions = physics.nudged("00000", steps, nudge, seed=1)
            offsets = positions[2:, 1] - truth.positions[2:, 1]
            np.testing.assert_allclose(np.linalg.norm(offsets, axis=1), nudge, atol=2e-5)  # the fall's
            np.testing.assert_allclose(offsets, offsets[:1].repeat(len(offsets), 0), atol=2e-5)  # float32
            assert quat_angle_deg(spun[1:], quaternions[2:, 1]).max() < 2e-4
            np.testing.assert_array_equal(positions[:2], truth.positions[:2])


def test_nudged_runs_grow_with_the_nudge_and_start_at_it(tosses, shapes):
    result = ceilings.evaluate_nudged(tosses, [1, 15], nudges=(0.0, 1e-3, 1e-2), assets=shapes)
    objects = sum(t.num_objects - 1 for t in tosses.trajectories.values())
    assert result["objects"] == objects and result["horizons"] == [1, 15]
    rows = result["nudges"]
    assert list(rows) == ["0 m", "0.001 m", "0.01 m"]
    assert rows["0 m"][0]["translation_rmse_m"] < FLOAT32_POSITION_TOLERANCE * 4
    for nudge, name in ((1e-3, "0.001 m"), (1e-2, "0.01 m")):
        assert rows[name][0]["translation_rmse_m"] == pytest.approx(nudge, rel=0.05)  # one frame on
    assert rows["0.01 m"][1]["translation_rmse_m"] > rows["0 m"][1]["translation_rmse_m"]
    from tests.bench import load_benchmark

    table = load_benchmark("physics_ceilings").markdown_table(result, "nudges", "nudge").splitlines()
    assert table[0].startswith("| nudge | steps |") and len(table) == 2 + 3 * 2
    assert table[2].startswith("| 0 m | 1 |") and table[-1].startswith("| 0.01 m | 15 |")
    again = ceilings.evaluate_nudged(tosses, [15], nudges=(1e-3,), assets=shapes)
    assert again["nudges"]["0.001 m"][0] == rows["0.001 m"][1]  # the seed fixes the directions
    with (
        ceilings.RestartedPyBullet(tosses, shapes) as physics,
        pytest.raises(FignetError, match="nudge must be a distance"),
    ):
        physics.nudged("00000", 1, -1e-3)


# ----------------------------------------------------------------------------- clear errors


def test_a_file_without_a_generator_config_is_refused(tosses, shapes):
    other = dataclasses.replace(tosses, attrs={"source": "elsewhere"})
    with pytest.raises(FignetError, match="make-dataset"):
        ceilings.ceiling_rollout(other, "00000", "velocity", 1, assets=shapes)


def test_unknown_states_and_trajectories_are_refused(tosses, shapes):
    with pytest.raises(FignetError, match="unknown state 'position'"):
        ceilings.ceiling_rollout(tosses, "00000", "position", 1, assets=shapes)
    with pytest.raises(FignetError, match="no trajectory '00007'"):
        ceilings.ceiling_rollout(tosses, "00007", "velocity", 1, assets=shapes)


def test_the_velocity_state_needs_recorded_velocities(tosses, shapes):
    trajectory = dataclasses.replace(tosses.trajectories["00000"], velocities=None, angular_velocities=None)
    old = dataclasses.replace(tosses, trajectories={"00000": trajectory})
    with pytest.raises(FignetError, match="recorded velocities"):
        ceilings.ceiling_rollout(old, "00000", "velocity", 1, assets=shapes)
    positions, _ = ceilings.ceiling_rollout(old, "00000", "finite-difference", 1, assets=shapes)
    assert positions.shape[0] == 3


def test_shapes_that_did_not_make_the_file_are_refused(tosses, shapes):
    import trimesh

    bigger_ball = shape("ball", trimesh.creation.icosphere(subdivisions=2, radius=1.5))
    with pytest.raises(FignetError, match="'ball' is not the one"):
        ceilings.RestartedPyBullet(tosses, [shapes[0], bigger_ball, shapes[2]])
    with pytest.raises(FignetError, match="no asset given"):
        ceilings.ceiling_rollout(tosses, "00000", "velocity", 1, assets=shapes[:1])
