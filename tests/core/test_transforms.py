"""Quaternions and rigid transforms against scipy's Rotation, round trips and compositions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fignetctl.core.transforms import (
    matrix_to_quat,
    quat_angle_deg,
    quat_conjugate,
    quat_from_axis_angle,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
    quat_wxyz_to_xyzw,
    quat_xyzw_to_wxyz,
    random_quaternions,
    transform_points,
)


@pytest.fixture
def quaternions():
    return random_quaternions(np.random.default_rng(0), 500)


def scipy_rotation(quaternions_wxyz):
    return Rotation.from_quat(quat_wxyz_to_xyzw(quaternions_wxyz))


def test_random_quaternions_are_unit_with_nonnegative_w(quaternions):
    assert quaternions.shape == (500, 4)
    assert np.allclose(np.linalg.norm(quaternions, axis=-1), 1.0)
    assert np.all(quaternions[:, 0] >= 0)
    # Uniform rotations: the mean rotation matrix of many is close to zero.
    many = random_quaternions(np.random.default_rng(1), 20000)
    assert np.abs(quat_to_matrix(many).mean(axis=0)).max() < 0.03


def test_quat_to_matrix_matches_scipy_and_is_a_rotation(quaternions):
    matrices = quat_to_matrix(quaternions)
    assert np.allclose(matrices, scipy_rotation(quaternions).as_matrix(), atol=1e-14)
    assert np.allclose(np.linalg.det(matrices), 1.0)


def test_matrix_to_quat_round_trips_to_plus_or_minus_q(quaternions):
    recovered = matrix_to_quat(quat_to_matrix(quaternions))
    sign = np.sign(np.sum(recovered * quaternions, axis=-1, keepdims=True))
    assert np.allclose(recovered, sign * quaternions, atol=1e-14)
    assert np.all(recovered[:, 0] >= 0)


def test_matrix_to_quat_near_half_turns():
    axes = np.random.default_rng(2).normal(size=(300, 3))
    angles = np.pi - np.r_[0.0, 1e-12, 1e-8, 1e-4][np.arange(300) % 4]
    quaternions = quat_from_axis_angle(axes, angles)
    recovered = matrix_to_quat(quat_to_matrix(quaternions))
    assert np.allclose(np.abs(np.sum(recovered * quaternions, axis=-1)), 1.0, atol=1e-14)
    assert np.allclose(np.linalg.norm(recovered, axis=-1), 1.0)


def test_matrix_to_quat_matches_scipy_for_batched_matrices():
    matrices = Rotation.random(24, random_state=3).as_matrix().reshape(2, 3, 4, 3, 3)
    expected = quat_xyzw_to_wxyz(Rotation.from_matrix(matrices.reshape(-1, 3, 3)).as_quat())
    expected = expected.reshape(2, 3, 4, 4)
    expected *= np.where(expected[..., :1] < 0, -1.0, 1.0)
    assert np.allclose(matrix_to_quat(matrices), expected, atol=1e-14)


def test_multiply_composes_rotations_and_conjugate_inverts(quaternions):
    other = random_quaternions(np.random.default_rng(4), 500)
    composed = quat_to_matrix(quat_multiply(quaternions, other))
    assert np.allclose(composed, quat_to_matrix(quaternions) @ quat_to_matrix(other), atol=1e-14)
    identity = quat_multiply(quat_conjugate(quaternions), quaternions)
    assert np.allclose(identity, [1.0, 0, 0, 0], atol=1e-15)


def test_rotate_matches_the_matrix(quaternions):
    vectors = np.random.default_rng(5).normal(size=(500, 3))
    expected = np.einsum("nij,nj->ni", quat_to_matrix(quaternions), vectors)
    assert np.allclose(quat_rotate(quaternions, vectors), expected, atol=1e-14)
    assert np.allclose(quat_rotate(quaternions * 7.0, vectors), quat_rotate(quaternions, vectors))


def test_axis_angle_against_scipy_and_zero_axis():
    rng = np.random.default_rng(6)
    axes, angles = rng.normal(size=(100, 3)), rng.uniform(-7, 7, 100)
    unit_axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    expected = Rotation.from_rotvec(unit_axes * angles[:, None]).as_matrix()
    assert np.allclose(quat_to_matrix(quat_from_axis_angle(axes, angles)), expected, atol=1e-14)
    assert np.array_equal(quat_from_axis_angle(np.zeros((2, 3)), [1.0, 2.0]), [[1.0, 0, 0, 0]] * 2)
    assert quat_from_axis_angle([0.0, 0, 1], np.full(5, 0.3)).shape == (5, 4)


def test_angle_in_degrees_double_cover_and_no_nan(quaternions):
    half_turn = quat_from_axis_angle([0.0, 1, 0], np.radians(37.0))
    assert np.isclose(quat_angle_deg([1.0, 0, 0, 0], half_turn), 37.0)
    assert np.allclose(quat_angle_deg(quaternions, -quaternions), 0.0, atol=1e-6)
    assert np.allclose(quat_angle_deg(quaternions, quaternions * (1 + 1e-15)), 0.0, atol=1e-6)
    assert np.isclose(quat_angle_deg([1.0, 0, 0, 0], [0.0, 0, 0, 1]), 180.0)
    other = random_quaternions(np.random.default_rng(7), 500)
    expected = np.degrees((scipy_rotation(quaternions).inv() * scipy_rotation(other)).magnitude())
    assert np.allclose(quat_angle_deg(quaternions, other), expected, atol=1e-9)
    assert np.isfinite(quat_angle_deg(np.zeros(4), quaternions)).all()


def test_normalize_scales_to_unit_and_zero_becomes_identity():
    result = quat_normalize(np.array([[0.0, 0, 0, 0], [2.0, 0, 0, 0], [1.0, 1, 1, 1]]))
    assert np.allclose(result, [[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0.5, 0.5, 0.5, 0.5]])


def test_transform_points_applies_scale_rotation_translation(quaternions):
    rng = np.random.default_rng(8)
    vertices, positions, scales = rng.normal(size=(7, 3)), rng.normal(size=(500, 3)), rng.uniform(0.5, 2, 500)
    world = transform_points(vertices, scales, positions, quaternions)
    rotated = np.einsum("nij,vj->nvi", quat_to_matrix(quaternions), vertices)
    expected = rotated * scales[:, None, None] + positions[:, None]
    assert world.shape == (500, 7, 3) and np.allclose(world, expected, atol=1e-13)
    frames = transform_points(vertices, 1.5, positions.reshape(10, 50, 3), quaternions.reshape(10, 50, 4))
    assert frames.shape == (10, 50, 7, 3)


def test_transform_composition(quaternions):
    rng = np.random.default_rng(9)
    vertices = rng.normal(size=(5, 3))
    first_q, second_q = quaternions[:100], quaternions[100:200]
    first_p, second_p = rng.normal(size=(2, 100, 3))
    once = transform_points(transform_points(vertices, 1.0, first_p, first_q), 1.0, second_p, second_q)
    composed_q = quat_multiply(second_q, first_q)
    composed_p = quat_rotate(second_q, first_p) + second_p
    assert np.allclose(once, transform_points(vertices, 1.0, composed_p, composed_q), atol=1e-13)


def test_xyzw_round_trip(quaternions):
    assert np.array_equal(quat_xyzw_to_wxyz(quat_wxyz_to_xyzw(quaternions)), quaternions)
    assert np.array_equal(quat_wxyz_to_xyzw([1.0, 2, 3, 4]), [2.0, 3, 4, 1])
