"""Training noise on the input history, as pure functions: the model never draws random numbers.

Choice: per-object rigid jitter, not per-vertex noise. At rollout time every step ends with
shape matching, so the network only ever sees rigid objects whose pose has drifted; per-object
noise reproduces that drift, while per-vertex noise would show it deformed shapes it never
meets. Each dynamic object o gets a small rotation R_o (a rotation vector with normal
components of std `rotation_std`, radians) about its centre of mass c_o and a translation t_o
(normal components of std `translation_std`, metres):

    x̃ = R_o · (x − c_o) + c_o + t_o     for its vertices; its centre moves to c_o + t_o

Apply it to the latest frame x_t only and leave x_{t−1} as it is: a random walk over the one
velocity of history (learning_to_simulate's scheme with one velocity puts all the noise on the
last position). The simulator then makes the target from the noisy x̃_t so that the ground-truth
x_{t+1} stays the answer: a = x_{t+1} − 2·x̃_t + x_{t−1}. Static objects get no noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch


@dataclasses.dataclass
class RigidPoseNoise:
    """One small rigid motion per object.

    translations : (O, 3) float
    rotation_vectors : (O, 3) float, axis · angle in radians
    """

    translations: torch.Tensor
    rotation_vectors: torch.Tensor


def sample_rigid_pose_noise(
    dynamic: torch.Tensor, translation_std: float, rotation_std: float, generator: torch.Generator
) -> RigidPoseNoise:
    """dynamic : (O,) bool, False for static objects, which get zero noise. Draws on the
    generator's device, in float32."""
    num_objects = dynamic.shape[0]
    device = generator.device
    translations = torch.randn(num_objects, 3, generator=generator, device=device) * translation_std
    rotation_vectors = torch.randn(num_objects, 3, generator=generator, device=device) * rotation_std
    keep = dynamic.to(device=device, dtype=translations.dtype)[:, None]
    return RigidPoseNoise(translations * keep, rotation_vectors * keep)


def rotation_matrices_from_rotation_vectors(rotation_vectors: torch.Tensor) -> torch.Tensor:
    """(O, 3) axis · angle -> (O, 3, 3) rotation matrices, exact at zero angle."""
    x, y, z = rotation_vectors.unbind(dim=-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(-1, 3, 3)
    return torch.linalg.matrix_exp(skew)


def apply_rigid_pose_noise(
    positions: torch.Tensor,
    object_index: torch.Tensor,
    centres: torch.Tensor,
    noise: RigidPoseNoise,
) -> torch.Tensor:
    """Move each point rigidly with its object's noise.

    positions : (P, 3) float, vertices (or centres) at frame t
    object_index : (P,) long, the object each point belongs to
    centres : (O, 3) float, the objects' centres of mass at frame t
    returns : (P, 3) float
    """
    rotations = rotation_matrices_from_rotation_vectors(noise.rotation_vectors).to(positions.dtype)
    point_centres = centres[object_index]
    offsets = positions - point_centres
    rotated_offsets = torch.einsum("pij,pj->pi", rotations[object_index], offsets)
    return point_centres + rotated_offsets + noise.translations.to(positions.dtype)[object_index]


def apply_rigid_pose_noise_to_poses(positions, quaternions, noise: RigidPoseNoise):
    """The same motion applied to object poses: centre c_o + t_o, rotation R_o · q_o, so the
    vertices of the noisy poses are `apply_rigid_pose_noise` of the vertices of the clean ones.

    positions (O, 3), quaternions (O, 4) w x y z -> float64 numpy copies
    """
    from fignetctl.core.transforms import quat_from_rotation_vector, quat_multiply

    turned = quat_multiply(
        quat_from_rotation_vector(noise.rotation_vectors.double().cpu().numpy()), quaternions
    )
    return np.asarray(positions, np.float64) + noise.translations.double().cpu().numpy(), turned
