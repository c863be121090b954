import math

import numpy as np
import torch

from fignetctl.core.model.noise import (
    apply_rigid_pose_noise,
    rotation_matrices_from_rotation_vectors,
    sample_rigid_pose_noise,
)


def two_boxes_and_a_floor():
    """Points of three objects (floor static) and their centres: (P, 3), (P,), (O, 3)."""
    generator = torch.Generator().manual_seed(0)
    positions = torch.randn(24, 3, generator=generator) + torch.tensor([5.0, -2.0, 1.0])
    object_index = torch.arange(24) % 3
    centres = torch.stack([positions[object_index == o].mean(dim=0) for o in range(3)])
    return positions, object_index, centres


def test_rotation_vectors_give_rotations():
    quarter_turn_about_z = rotation_matrices_from_rotation_vectors(torch.tensor([[0.0, 0.0, math.pi / 2]]))[0]
    torch.testing.assert_close(
        quarter_turn_about_z @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0])
    )
    rotations = rotation_matrices_from_rotation_vectors(torch.randn(50, 3) * 0.1)
    identity = torch.eye(3).expand(50, 3, 3)
    torch.testing.assert_close(rotations @ rotations.transpose(1, 2), identity, atol=1e-6, rtol=0)
    torch.testing.assert_close(torch.linalg.det(rotations), torch.ones(50))
    torch.testing.assert_close(rotation_matrices_from_rotation_vectors(torch.zeros(1, 3))[0], torch.eye(3))


def test_noise_moves_each_object_rigidly_and_leaves_static_objects_alone():
    positions, object_index, centres = two_boxes_and_a_floor()
    dynamic = torch.tensor([True, True, False])
    noise = sample_rigid_pose_noise(dynamic, 0.01, 0.05, torch.Generator().manual_seed(1))
    noisy = apply_rigid_pose_noise(positions, object_index, centres, noise)
    for o in range(3):
        mine = object_index == o
        torch.testing.assert_close(
            torch.cdist(noisy[mine], noisy[mine]),
            torch.cdist(positions[mine], positions[mine]),
            atol=1e-5,
            rtol=0,
        )
    torch.testing.assert_close(noisy[object_index == 2], positions[object_index == 2])
    moved_centres = apply_rigid_pose_noise(centres, torch.arange(3), centres, noise)
    torch.testing.assert_close(moved_centres, centres + noise.translations)
    assert (noisy[object_index == 0] - positions[object_index == 0]).abs().max() > 1e-4


def test_noise_has_the_requested_spread_and_is_reproducible():
    dynamic = torch.ones(20000, dtype=torch.bool)
    noise = sample_rigid_pose_noise(dynamic, 0.003, 0.02, torch.Generator().manual_seed(2))
    assert abs(noise.translations.std().item() / 0.003 - 1) < 0.03
    assert abs(noise.rotation_vectors.std().item() / 0.02 - 1) < 0.03
    again = sample_rigid_pose_noise(dynamic, 0.003, 0.02, torch.Generator().manual_seed(2))
    torch.testing.assert_close(again.translations, noise.translations)


def test_noise_on_poses_moves_the_vertices_as_the_noise_on_points_does():
    from fignetctl.core.model.noise import apply_rigid_pose_noise_to_poses
    from fignetctl.core.transforms import quat_from_rotation_vector, quat_to_matrix

    rng = np.random.default_rng(3)
    centres = rng.normal(size=(3, 3))
    quaternions = quat_from_rotation_vector(rng.normal(size=(3, 3)))
    rest = rng.normal(size=(3, 5, 3))
    world = np.einsum("oij,okj->oki", quat_to_matrix(quaternions), rest) + centres[:, None]
    noise = sample_rigid_pose_noise(
        torch.tensor([True, True, False]), 0.01, 0.3, torch.Generator().manual_seed(4)
    )
    noisy_centres, noisy_quaternions = apply_rigid_pose_noise_to_poses(centres, quaternions, noise)
    from_poses = np.einsum("oij,okj->oki", quat_to_matrix(noisy_quaternions), rest) + noisy_centres[:, None]
    owner = torch.arange(3).repeat_interleave(5)
    from_points = apply_rigid_pose_noise(
        torch.from_numpy(world.reshape(-1, 3)), owner, torch.from_numpy(centres), noise
    )
    np.testing.assert_allclose(
        from_poses.reshape(-1, 3), from_points.numpy(), atol=1e-6
    )  # noise.py builds its matrices in float32
    np.testing.assert_array_equal(noisy_centres[2], centres[2])
