"""Shape matching recovers rigid transforms and never reflects, for every point layout."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from fignetctl.core.shape_matching import (
    _fit_rigid_transform_torch_native,
    fit_rigid_transform,
    fit_rigid_transform_torch,
)


def random_rigid_transforms(rng, count):
    """Rotations (count, 3, 3) and translations (count, 3), some far from the origin."""
    rotations = Rotation.random(count, random_state=rng.integers(1 << 31)).as_matrix()
    translations = rng.normal(0, 1, (count, 3)) * 10.0 ** rng.integers(-2, 4, (count, 1))
    return rotations, translations


def apply_transform(rotations, translations, points):
    """R p + t for (..., 3, 3), (..., 3), (..., N, 3)."""
    return np.einsum("...ij,...nj->...ni", rotations, points) + translations[..., None, :]


def assert_proper_rotations(rotations, atol=1e-9):
    rotations = np.asarray(rotations, dtype=np.float64)
    assert np.isfinite(rotations).all()
    identity = np.broadcast_to(np.eye(3), rotations.shape)
    assert np.allclose(np.swapaxes(rotations, -1, -2) @ rotations, identity, atol=atol)
    assert np.allclose(np.linalg.det(rotations), 1.0, atol=atol)


def test_recovers_random_transforms_of_random_points():
    rng = np.random.default_rng(0)
    rotations, translations = random_rigid_transforms(rng, 200)
    source = rng.normal(0, 0.5, (200, 40, 3))
    rotation, translation = fit_rigid_transform(source, apply_transform(rotations, translations, source))
    assert np.allclose(rotation, rotations, atol=1e-9)
    assert np.allclose(translation, translations, atol=1e-8)


def test_leading_batch_dimensions_and_broadcast_source():
    rng = np.random.default_rng(1)
    rotations, translations = random_rigid_transforms(rng, 12)
    source = rng.normal(size=(30, 3))
    target = apply_transform(rotations, translations, source).reshape(3, 4, 30, 3)
    rotation, translation = fit_rigid_transform(source, target)
    assert rotation.shape == (3, 4, 3, 3) and translation.shape == (3, 4, 3)
    assert np.allclose(rotation.reshape(12, 3, 3), rotations, atol=1e-9)


def test_zero_weights_ignore_outliers():
    rng = np.random.default_rng(2)
    rotations, translations = random_rigid_transforms(rng, 1)
    source = rng.normal(size=(50, 3))
    target = apply_transform(rotations[0], translations[0], source)
    target[:10] += rng.normal(0, 5.0, (10, 3))
    weights = np.r_[np.zeros(10), rng.uniform(0.5, 2.0, 40)]
    rotation, translation = fit_rigid_transform(source, target, weights)
    assert np.allclose(rotation, rotations[0], atol=1e-9)
    assert np.allclose(translation, translations[0], atol=1e-8)


def test_all_zero_weights_fall_back_to_uniform():
    rng = np.random.default_rng(3)
    source = rng.normal(size=(20, 3))
    uniform = fit_rigid_transform(source, source + 1.0)
    zero = fit_rigid_transform(source, source + 1.0, np.zeros(20))
    assert np.allclose(uniform[0], zero[0]) and np.allclose(uniform[1], zero[1])


def test_reflected_target_still_gives_a_rotation():
    rng = np.random.default_rng(4)
    source = rng.normal(size=(100, 40, 3))
    mirrored = source * np.array([1.0, 1.0, -1.0])
    rotation, translation = fit_rigid_transform(source, mirrored)
    assert_proper_rotations(rotation)
    assert np.isfinite(translation).all()


def planar_source(rng, count, thickness):
    """(count, 3) points in the z = 0 plane, or within `thickness` of it."""
    points = rng.normal(size=(count, 3))
    points[:, 2] *= thickness
    return points


@pytest.mark.parametrize("thickness", [0.0, 1e-9, 1e-5])
def test_planar_and_near_planar_sets_are_recovered(thickness):
    rng = np.random.default_rng(5)
    rotations, translations = random_rigid_transforms(rng, 50)
    source = np.stack([planar_source(rng, 25, thickness) for _ in range(50)])
    rotation, translation = fit_rigid_transform(source, apply_transform(rotations, translations, source))
    assert_proper_rotations(rotation)
    assert np.allclose(rotation, rotations, atol=1e-7) and np.allclose(translation, translations, atol=1e-6)


def test_collinear_points_fit_exactly_with_a_proper_rotation():
    rng = np.random.default_rng(6)
    rotations, translations = random_rigid_transforms(rng, 30)
    source = rng.normal(size=(30, 1, 1)) + np.linspace(-1, 1, 12)[None, :, None] * rng.normal(size=(30, 1, 3))
    target = apply_transform(rotations, translations, source)
    rotation, translation = fit_rigid_transform(source, target)
    assert_proper_rotations(rotation)
    assert np.allclose(apply_transform(rotation, translation, source), target, atol=1e-7)


def test_coincident_points_give_a_rotation_and_the_offset():
    source = np.full((2, 8, 3), 0.5)
    target = np.full((2, 8, 3), -2.0)
    rotation, translation = fit_rigid_transform(source, target)
    assert_proper_rotations(rotation)
    assert np.allclose(apply_transform(rotation, translation, source), target)


def test_single_point_and_float32_inputs():
    rotation, translation = fit_rigid_transform(np.ones((1, 3), np.float32), np.zeros((1, 3), np.float32))
    assert rotation.dtype == np.float64
    assert_proper_rotations(rotation)
    assert np.allclose(rotation @ np.ones(3) + translation, 0.0)


def mixed_layouts(rng, count=64):
    """Source, target and weights with noise, a mirrored copy and coincident targets."""
    rotations, translations = random_rigid_transforms(rng, count)
    source = rng.normal(size=(count, 30, 3))
    target = apply_transform(rotations, translations, source) + rng.normal(0, 1e-3, (count, 30, 3))
    target[0] = source[0] * [1.0, 1.0, -1.0]  # a mirrored copy
    target[1] = 3.0  # all target points coincide
    return source, target, rng.uniform(0, 1, (count, 30))


@pytest.mark.parametrize("variant", ["public", "torch_ops"])
def test_torch_variants_match_numpy(variant):
    source, target, weights = mixed_layouts(np.random.default_rng(7))
    expected = fit_rigid_transform(source, target, weights)
    tensors = torch.tensor(source), torch.tensor(target), torch.tensor(weights)
    if variant == "public":
        found = fit_rigid_transform_torch(*tensors)
    else:
        found = _fit_rigid_transform_torch_native(torch, *tensors)
    assert found[0].dtype == torch.float64
    # Row 1 has no preferred rotation (any one fits coincident targets): compare the others.
    compared = np.r_[0, 2:64]
    assert np.allclose(found[0].numpy()[compared], expected[0][compared], atol=1e-9)
    assert np.allclose(found[1].numpy()[compared], expected[1][compared], atol=1e-8)
    assert_proper_rotations(found[0].numpy())
    source_centroid = np.average(source[1], axis=0, weights=weights[1])
    assert np.allclose(found[1].numpy()[1], 3.0 - found[0].numpy()[1] @ source_centroid)


def test_torch_variant_keeps_float32_and_recovers_transforms():
    rng = np.random.default_rng(8)
    rotations, translations = random_rigid_transforms(rng, 16)
    source = rng.normal(size=(16, 50, 3))
    target = apply_transform(rotations, translations, source)
    source_32 = torch.tensor(source, dtype=torch.float32)
    target_32 = torch.tensor(target, dtype=torch.float32)
    rotation, translation = fit_rigid_transform_torch(source_32, target_32)
    assert rotation.dtype == torch.float32 and translation.dtype == torch.float32
    assert np.allclose(rotation.numpy(), rotations, atol=1e-4)
    assert_proper_rotations(rotation.numpy(), atol=1e-5)
    collinear = torch.linspace(0, 1, 10, dtype=torch.float32)[:, None] * torch.tensor([1.0, 2.0, 3.0])
    rotation, _ = fit_rigid_transform_torch(collinear, collinear + 1.0)
    assert_proper_rotations(rotation.numpy(), atol=1e-5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_torch_variant_on_the_gpu_matches_numpy():
    source, target, weights = mixed_layouts(np.random.default_rng(9))
    expected = fit_rigid_transform(source, target, weights)
    tensors = [torch.tensor(array, device="cuda") for array in (source, target, weights)]
    rotation, translation = fit_rigid_transform_torch(*tensors)
    assert rotation.device.type == "cuda"
    assert np.allclose(rotation.cpu().numpy()[2:], expected[0][2:], atol=1e-9)
    assert np.allclose(translation.cpu().numpy()[2:], expected[1][2:], atol=1e-8)
