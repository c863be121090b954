"""`calm_weight` and `rest_weight`: extra loss weight on the vertices of objects that the
recording moves in free fall or keeps at rest, where small errors add up over a rollout."""

import dataclasses

import numpy as np
import pytest
import torch

from fignetctl.core.model.learnability import regime_errors, step_response
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.training import (
    CALM_TOLERANCE,
    REGIMES,
    TrainingBatches,
    TrainingSettings,
    calm_vertices,
    make_trainer,
    object_regimes,
    row_weights,
    simulator_config_for,
)
from fignetctl.core.trajectory import write_trajectories
from tests.conftest import bouncing_box_file, box_drop_file

GRAVITY = (0.0, 0.0, -10.0)
VELOCITIES = dataclasses.replace(
    simulator_config_for("fignet-star", "tiny", 0.1, state="velocities"), gravity=GRAVITY, dt=1 / 60
)
POSITIONS = dataclasses.replace(
    simulator_config_for("fignet-star", "tiny", 0.1, state="positions"), gravity=GRAVITY, dt=1 / 60
)


def _scene(data, config=VELOCITIES):
    (scene,) = scenes_from_data(data, config, TRAINING_STATIC_REACH)
    return scene


def _edited(data, **arrays):
    trajectory = data.trajectories["00000"]
    return dataclasses.replace(data, trajectories={"00000": dataclasses.replace(trajectory, **arrays)})


@pytest.mark.parametrize("config", [VELOCITIES, POSITIONS], ids=["velocities", "positions"])
def test_a_spinning_box_in_free_fall_is_calm_in_every_frame(config):
    scene = _scene(box_drop_file(frames=10, spin=3.0, height=2.0), config)
    for frame in range(1, 9):
        calm = calm_vertices(scene, frame, GRAVITY, config.uses_velocities)
        assert calm.shape == (8,) and calm.all(), frame


@pytest.mark.parametrize("config", [VELOCITIES, POSITIONS], ids=["velocities", "positions"])
def test_a_box_at_rest_is_calm_and_its_bounce_is_not(config):
    data = box_drop_file(frames=10, spin=0.0, height=0.5)
    positions = np.array(data.trajectories["00000"].positions)
    positions[:, 1] = positions[0, 1]
    resting = _edited(data, positions=positions, velocities=np.zeros((10, 2, 3), np.float32))
    velocity_state = config.uses_velocities
    assert all(calm_vertices(_scene(resting, config), t, GRAVITY, velocity_state).all() for t in range(1, 9))
    bouncing = _scene(bouncing_box_file(impact=6), config)
    # the velocity state's target spans t -> t + 1 (the flip is from frame 5 to 6); a two-frame
    # model's spans t - 1 -> t + 1, so frame 6 changes its motion as well
    bounce = {5} if velocity_state else {6}
    for frame in range(1, 11):
        assert calm_vertices(bouncing, frame, GRAVITY, velocity_state).all() == (frame not in bounce), frame


def test_a_change_of_spin_just_past_the_tolerance_is_not_calm():
    data = box_drop_file(frames=6, spin=3.0, height=2.0)
    reach = np.sqrt(3) / 2  # the unit box's corners from its centre
    tolerance = CALM_TOLERANCE * 10.0 * data.dt  # rad/s of angular velocity change at the corners
    angular = np.array(data.trajectories["00000"].angular_velocities)
    for factor, calm in ((0.9, True), (1.1, False)):
        changed = angular.copy()
        changed[3:, 1, 0] += factor * tolerance / reach
        scene = _scene(_edited(data, angular_velocities=changed))
        assert calm_vertices(scene, 2, GRAVITY).all() == calm
        assert calm_vertices(scene, 3, GRAVITY).all()  # no change from 3 to 4


def test_training_batches_weigh_calm_rows_and_leave_the_draws_alone(tmp_path):
    data = box_drop_file(frames=12, spin=0.0, height=2.0)
    scenes = scenes_from_data(bouncing_box_file(), VELOCITIES, TRAINING_STATIC_REACH) + scenes_from_data(
        data, VELOCITIES, TRAINING_STATIC_REACH
    )
    plain = TrainingSettings(batch_size=6, seed=3)
    weighted = dataclasses.replace(plain, calm_weight=4.0)
    seen = set()
    for step in range(20):
        ordinary, heavier = (
            TrainingBatches(scenes, VELOCITIES, plain)[step],
            TrainingBatches(scenes, VELOCITIES, weighted)[step],
        )
        assert "weights" not in ordinary
        torch.testing.assert_close(heavier["targets"], ordinary["targets"], rtol=0, atol=0)
        weights = heavier["weights"].reshape(6, 8)  # 8 dynamic vertices per example
        assert set(weights.unique().tolist()) <= {1.0, 5.0} and (weights == weights[:, :1]).all()
        seen |= set(weights[:, 0].tolist())
    assert seen == {1.0, 5.0}  # the bounce is drawn, and it weighs 1


def test_a_calm_weighted_run_trains_and_resumes_with_its_weight(tmp_path):
    path = write_trajectories(tmp_path / "bounce.h5", bouncing_box_file())
    config = TrainingSettings(steps=6, batch_size=3, pushforward=1, calm_weight=10.0, checkpoint_every=3)
    config = dataclasses.replace(config, normalizer_accumulation_steps=2)
    straight = make_trainer(path, VELOCITIES, config)
    straight.run()
    interrupted = make_trainer(path, VELOCITIES, config)
    interrupted.run(tmp_path / "half.pt", until_step=3)
    resumed = make_trainer(path, VELOCITIES, TrainingSettings(steps=6), resume_from=tmp_path / "half.pt")
    assert resumed.config.calm_weight == 10.0
    resumed.run()
    for name, value in straight.simulator.state_dict().items():
        torch.testing.assert_close(resumed.simulator.state_dict()[name], value, rtol=0, atol=0)


def test_object_regimes_of_a_bounce_and_of_a_rest():
    bouncing = _scene(bouncing_box_file(impact=6))
    assert object_regimes(bouncing, 5, GRAVITY)[1] == REGIMES.index("impact")
    for frame in (1, 4, 6, 10):
        assert object_regimes(bouncing, frame, GRAVITY)[1] == REGIMES.index("free fall"), frame
    data = box_drop_file(frames=6, spin=0.0, height=0.5)
    positions = np.array(data.trajectories["00000"].positions)
    positions[:, 1] = positions[0, 1]
    velocities = np.zeros((6, 2, 3), np.float32)
    velocities[3:, 1, 0] = 0.5 * CALM_TOLERANCE * 10.0 * data.dt  # a nudge below the tolerance: still at rest
    resting = _scene(_edited(data, positions=positions, velocities=velocities))
    assert object_regimes(resting, 2, GRAVITY)[1] == REGIMES.index("at rest or steady")
    velocities[3:, 1, 0] *= 4  # twice the tolerance, under the impact's 5 g dt²: other contact
    pushed = _scene(_edited(data, positions=positions, velocities=velocities))
    assert object_regimes(pushed, 2, GRAVITY)[1] == REGIMES.index("other contact")


class _SinkingTwoFrameModel:
    """Steps every scene to its recorded next frame, 1 mm lower: a two-frame model whose only
    error is a_x = (0, 0, −1 mm) on every vertex."""

    config = POSITIONS

    def predict(self, geometry, positions, quaternions, velocities=None):
        return positions[2] - [0.0, 0.0, 0.001], quaternions[2], None, None


def test_regime_errors_of_a_model_that_sinks_one_millimetre_a_frame():
    scenes = scenes_from_data(bouncing_box_file(impact=6), POSITIONS, TRAINING_STATIC_REACH)
    regimes = regime_errors(_SinkingTwoFrameModel(), scenes)
    free, impact = regimes["free fall"], regimes["impact"]
    # frames t = 1 … 10; a two-frame model's target spans t − 1 → t + 1: the bounce is t = 6 alone
    assert free["share"] == pytest.approx(9 / 10) and impact["share"] == pytest.approx(1 / 10)
    assert regimes["at rest or steady"] == {"share": 0.0} == regimes["other contact"]
    for figures in (free, impact):
        assert figures["error_rms_mm"]["position"] == pytest.approx(1.0)
        assert figures["bias_mm"] == pytest.approx(-1.0)
    assert free["error_share"] == pytest.approx(0.9) and impact["error_share"] == pytest.approx(0.1)
    fall = 10.0 / 60**2  # g dt², m per frame
    assert free["target_rms_mm"]["position"] == pytest.approx(fall * 1e3, rel=1e-3)
    assert impact["target_rms_mm"]["position"] == pytest.approx((2 * 3.0 / 60 - fall) * 1e3, rel=1e-3)


def test_regime_errors_say_which_errors_lie_out_of_the_collision_radius():
    # the unit box's underside is 1.45 m above the floor at the bounce (t = 6) and 1.48 m or
    # more at every other frame: a radius of 1.47 m reaches the floor at the bounce alone
    # (the floor kept within 10 m of the box, not training's 1 m)
    scenes = scenes_from_data(bouncing_box_file(impact=6), POSITIONS, static_reach=10.0)
    regimes = regime_errors(_SinkingTwoFrameModel(), scenes, radii=(0.1, 1.47, 5.0))
    free, impact = regimes["free fall"]["out_of_reach"], regimes["impact"]["out_of_reach"]
    assert [free[r]["share"] for r in ("0.1", "1.47", "5")] == [1.0, 1.0, 0.0]
    assert [impact[r]["share"] for r in ("0.1", "1.47", "5")] == [1.0, 0.0, 0.0]
    assert free["0.1"]["error_share"] == pytest.approx(0.9) and free["5"]["error_share"] == 0.0
    assert impact["0.1"]["error_share"] == pytest.approx(0.1) and impact["1.47"]["error_share"] == 0.0
    assert "out_of_reach" not in regime_errors(_SinkingTwoFrameModel(), scenes)["impact"]


class _ShrunkResponseModel:
    """A velocity-state model that steps every scene to its recorded next poses, with `linear`
    times the recorded change of each object's velocity beyond free fall's and `angular` times
    its recorded change of spin."""

    config = VELOCITIES

    def __init__(self, scene, linear, angular):
        self.scene, self.linear, self.angular = scene, linear, angular

    def predict(self, geometry, positions, quaternions, velocities=None):
        scene = self.scene
        t = next(t for t in range(len(scene.positions)) if np.array_equal(scene.positions[t], positions[1]))
        linear, angular = velocities
        fall = np.array(GRAVITY) * scene.dt
        return (
            positions[2],
            quaternions[2],
            linear + fall + self.linear * (scene.velocities[t + 1] - linear - fall),
            angular + self.angular * (scene.angular_velocities[t + 1] - angular),
        )


def test_the_response_says_how_much_of_each_change_of_motion_a_model_follows():
    data = bouncing_box_file(impact=6)
    angular = np.zeros((12, 2, 3), np.float32)
    angular[6:, 1, 0] = 2.0  # the bounce (frame 5 -> 6) also sets it spinning
    scene = _scene(_edited(data, angular_velocities=angular))
    regimes = regime_errors(_ShrunkResponseModel(scene, linear=0.25, angular=0.5), [scene])
    impact, free = regimes["impact"]["response"], regimes["free fall"]["response"]
    assert impact["share"] == pytest.approx(1 / 10) and free["share"] == pytest.approx(9 / 10)
    assert impact["linear"]["target_rms"] == pytest.approx(6.0, rel=1e-4)  # -3 m/s to +3 m/s
    assert impact["linear"]["error_rms"] == pytest.approx(0.75 * 6.0, rel=1e-4)
    assert impact["linear"]["captured"] == pytest.approx(0.25, rel=1e-5)
    assert impact["angular"]["target_rms"] == pytest.approx(2.0)
    assert impact["angular"]["captured"] == pytest.approx(0.5, rel=1e-5)
    # in free fall nothing changes but float rounding: no slope to speak of, and no error
    for part in ("linear", "angular"):
        assert free[part]["captured"] is None and free[part]["error_rms"] < 1e-5
    positions_state = regime_errors(
        _SinkingTwoFrameModel(), scenes_from_data(data, POSITIONS, TRAINING_STATIC_REACH)
    )
    assert "response" not in positions_state["free fall"]


def test_step_response_is_the_slope_through_zero():
    recorded = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    response = step_response(0.5 * recorded + [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], recorded)
    assert response["captured"] == pytest.approx(0.5)  # the part across the changes is not followed
    assert response["target_rms"] == pytest.approx(np.sqrt(2.5))
    assert response["error_rms"] == pytest.approx(np.sqrt((0.25 + 1 + 1 + 1) / 2))
    assert step_response(recorded, np.zeros((2, 3)))["captured"] is None
    assert step_response(np.zeros((0, 3)), np.zeros((0, 3))) == {
        "target_rms": 0.0,
        "error_rms": 0.0,
        "captured": None,
    }


def test_rest_weight_weighs_resting_rows_on_top_of_the_calm_weight():
    data = box_drop_file(frames=12, spin=0.0, height=0.5)
    positions = np.array(data.trajectories["00000"].positions)
    positions[:, 1] = positions[0, 1]
    resting = _scene(_edited(data, positions=positions, velocities=np.zeros((12, 2, 3), np.float32)))
    bouncing = _scene(bouncing_box_file(impact=6))
    rest = TrainingSettings(rest_weight=100.0)
    both = dataclasses.replace(rest, calm_weight=4.0)
    for frame in range(1, 10):
        assert (row_weights(resting, frame, VELOCITIES, rest) == 101.0).all()
        assert (row_weights(resting, frame, VELOCITIES, both) == 105.0).all()
        falling_or_bouncing = 1.0 if frame == 5 else 5.0  # frame 5 -> 6 is the bounce
        assert (row_weights(bouncing, frame, VELOCITIES, rest) == 1.0).all()
        assert (row_weights(bouncing, frame, VELOCITIES, both) == falling_or_bouncing).all()
    assert row_weights(resting, 1, VELOCITIES, TrainingSettings()) == 1.0
    batch = TrainingBatches([resting, bouncing], VELOCITIES, dataclasses.replace(rest, batch_size=8))[0]
    assert set(batch["weights"].unique().tolist()) == {1.0, 101.0}
