"""benchmarks/rest_response.py: what it gives each kind of model, and the responses it reads off."""

import types

import numpy as np
import pytest

from tests.bench import load_benchmark

rest_response = load_benchmark("rest_response")
DT = 1 / 30


class _Answers:
    """A stand-in simulator whose next frame moves every object by `moved` times the velocity it
    was given, leaving it `kept` times that velocity; it records what it was given."""

    def __init__(self, moved, kept, velocity_state):
        self.moved, self.kept = moved, kept
        self.config = types.SimpleNamespace(uses_velocities=velocity_state)
        self.given = []

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        self.given.append((positions.copy(), velocities))
        step = positions[1] - positions[0]  # what a two-frame model reads
        if velocities is not None:
            np.testing.assert_allclose(velocities[0] * DT, step, atol=1e-12)  # both carry v
            assert not velocities[1].any()
        after = None if velocities is None else velocities[0] * self.kept
        return positions[1] + self.moved * step, quaternions[1], after, None if after is None else after * 0


def _state():
    positions = np.zeros((4, 4, 3))  # frames t-1, t of a floor and three objects, two at rest
    positions[:, 1:, 0] = [0.0, 2.0, 4.0]
    positions[-1, 3] += [0.0, 0.0, -0.01]  # the third moved 1 cm in the last frame
    quaternions = np.tile([1.0, 0.0, 0.0, 0.0], (4, 4, 1))
    return positions, quaternions, np.array([True, False, False, False])


def test_moving_objects_are_lifted_away_and_only_the_resting_ones_answer():
    now, _, resting = rest_response.resting_state(*_state())
    np.testing.assert_array_equal(resting, [False, True, True, False])
    np.testing.assert_allclose(now[3], [4.0, 0.0, 49.99])
    np.testing.assert_allclose(now[:3, 2], 0.0)


@pytest.mark.parametrize(
    "moved, kept, velocity_state",
    [(0.0, None, False), (-1.0, None, False), (1.0, None, False), (0.5, 0.0, True), (0.9, 0.7, True)],
)
def test_the_responses_are_the_shares_of_the_velocity_moved_and_kept(moved, kept, velocity_state):
    """A model that moves an object m·v and leaves it k·v answers moved = m (k = m − 1) and
    kept = k in every direction, and nothing from exact rest."""
    positions, quaternions, static = _state()
    now, turned, resting = rest_response.resting_state(positions, quaternions, static)
    model = _Answers(moved, kept, velocity_state)
    geometry = types.SimpleNamespace()
    found_moved, found_kept, from_rest = rest_response.responses(
        lambda v: rest_response.model_step(model, geometry, now, turned, resting, v, DT)
    )
    assert found_moved.shape == (12,)  # two resting objects, six directions
    np.testing.assert_allclose(found_moved, moved, atol=1e-12)
    if velocity_state:
        np.testing.assert_allclose(found_kept, kept, atol=1e-12)
    else:
        assert found_kept is None
    np.testing.assert_allclose(from_rest, 0.0, atol=1e-9)
    summary = rest_response.summarise(found_moved, found_kept, from_rest)
    assert summary["k_p10_p50_p90"] == [round(moved - 1.0, 3)] * 3
    assert ("kept_p10_p50_p90" in summary) == velocity_state
    # the lifted object was given no velocity; the resting ones v along the six directions
    given_positions, _ = model.given[0]
    np.testing.assert_allclose(
        given_positions[1] - given_positions[0], [[0, 0, 0]] + [[0.003, 0, 0]] * 2 + [[0, 0, 0]]
    )


class _Creep:
    """A stand-in velocity-state simulator that moves every dynamic object 1 mm along x a step."""

    config = types.SimpleNamespace(uses_velocities=True)

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        moved = positions[1] + np.where(geometry.static[:, None], 0.0, [0.001, 0.0, 0.0])
        return moved, quaternions[1], velocities[0], velocities[1]


def test_the_drift_is_how_far_a_resting_object_has_moved_after_the_steps():
    """A box resting on the floor in its last two frames, rolled out 7 steps from there by a
    model that creeps 1 mm a step, has moved 7 mm (the frames before, where it fell, are not
    where the rollout starts)."""
    from fignetctl.core.model.rollout import guards_for
    from fignetctl.core.model.scene_data import scene_from_trajectory
    from fignetctl.core.model.simulator import SimulatorConfig
    from tests.conftest import box_drop_file

    data = box_drop_file(frames=6, dt=DT, spin=0.0, height=2.0)
    trajectory = data.trajectories["00000"]
    trajectory.positions[-2:, 1] = [0.0, 0.0, 0.5]  # at rest on the floor in its last two frames
    trajectory.velocities[-2:] = 0.0
    scene = scene_from_trajectory(data, "00000", SimulatorConfig())
    guards = guards_for(DT, data.gravity, False, False, False)
    drift = rest_response.resting_drift(_Creep(), scene, 7, guards)
    np.testing.assert_allclose(drift, [[0.007, 0.0, 0.0]], atol=1e-9)


def test_the_drift_summary_splits_the_displacements_along_and_across_gravity():
    displacements = np.array([[0.03, 0.04, 0.0], [0.0, 0.0, -0.02], [0.0, 0.0, 0.005]])
    summary = rest_response.drift_summary(displacements, (0.0, 0.0, -10.0), 60, False)
    assert summary["objects"] == 3 and summary["objects_within_1cm"] == 1
    assert summary["metres_p10_p50_p90_max"][1:] == [0.02, 0.044, 0.05]
    assert summary["down_metres_p10_p50_p90"][1] == 0.0  # sinking 2 cm counts +, rising 5 mm -
    np.testing.assert_allclose(
        np.percentile([0.0, 0.02, -0.005], [10, 50, 90]).round(4), summary["down_metres_p10_p50_p90"]
    )
    assert summary["across_metres_p10_p50_p90"][1] == 0.0 and summary["across_metres_p10_p50_p90"][2] == 0.04


def test_bf16_difference_is_what_bfloat16_rounding_moves_the_step_from_rest():
    """A step of (1 + 2^-10) · 2^-10 m computed by a matrix product: under autocast 1 + 2^-10
    rounds to 1 in bfloat16 (7 stored mantissa bits; 2^-10 itself is exact), so the step moves
    2^-20 m less; exact arithmetic (a step without a product) answers 0."""
    import torch

    def product_step(velocity):
        moved = torch.tensor([[1.0 + 2.0**-10]]) @ torch.tensor([[2.0**-10, 0.0, 0.0]])
        return moved.float().numpy().astype(np.float64), None

    np.testing.assert_allclose(rest_response.bf16_difference(product_step), [2.0**-20 * 1000], rtol=1e-6)
    np.testing.assert_array_equal(
        rest_response.bf16_difference(lambda velocity: (np.full((2, 3), 1e-3), None)), [0.0, 0.0]
    )
