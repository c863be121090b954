"""benchmarks/calm_spin.py: a calm object keeps its spin, any other the network's."""

import dataclasses

import numpy as np
import pytest

from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.training import simulator_config_for
from fignetctl.core.transforms import quat_from_rotation_vector, quat_multiply
from tests.bench import load_benchmark
from tests.conftest import box_drop_file

calm_spin = load_benchmark("calm_spin")
GRAVITY = np.array([0.0, 0.0, -10.0])
CONFIG = dataclasses.replace(
    simulator_config_for("fignet-star", "tiny", 0.1, state="velocities"), gravity=tuple(GRAVITY), dt=1 / 30
)


class _MadeUpSpin:
    """Adds 1 rad/s of spin about x to every object each step and `kick` m/s to its velocity
    beyond free fall's; the poses it returns are frame t's."""

    config = CONFIG

    def __init__(self, kick):
        self.kick = kick

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        linear, angular = velocities
        return (
            positions[1].copy(),
            quaternions[1].copy(),
            linear + GRAVITY * CONFIG.dt + [self.kick, 0.0, 0.0],
            angular + [1.0, 0.0, 0.0],
        )


def _inputs():
    (scene,) = scenes_from_data(box_drop_file(frames=8, spin=2.0, height=3.0), CONFIG, TRAINING_STATIC_REACH)
    velocities = (scene.velocities[1], scene.angular_velocities[1])
    return scene, scene.positions[0:3], scene.quaternions[0:3], velocities


@pytest.mark.parametrize("oracle", [False, True], ids=["own", "oracle"])
def test_a_calm_object_keeps_its_spin_and_turns_at_it(oracle):
    scene, positions, quaternions, velocities = _inputs()
    proxy = calm_spin.CalmSpin(_MadeUpSpin(kick=0.0), scene, oracle=oracle)  # the box falls freely
    _, quaternion, _, angular = proxy.predict(scene.geometry, positions, quaternions, velocities=velocities)
    box = 1
    np.testing.assert_array_equal(angular[box], velocities[1][box])
    turned = quat_multiply(quat_from_rotation_vector(velocities[1][box] * CONFIG.dt), quaternions[1][box])
    np.testing.assert_allclose(quaternion[box], turned, atol=1e-12)
    assert np.linalg.norm(velocities[1][box]) > 1.0  # it does spin, so keeping it is not standing still
    assert (proxy.kept, proxy.dynamic_steps, proxy.steps) == (1, 1, 1)


def test_an_object_the_network_kicks_keeps_the_networks_spin():
    scene, positions, quaternions, velocities = _inputs()
    network = _MadeUpSpin(kick=5.0)
    proxy = calm_spin.CalmSpin(network, scene)
    expected = network.predict(scene.geometry, positions, quaternions, velocities=velocities)
    predicted = proxy.predict(scene.geometry, positions, quaternions, velocities=velocities)
    for value, wanted in zip(predicted, expected):
        np.testing.assert_array_equal(value, wanted)
    assert proxy.kept == 0
