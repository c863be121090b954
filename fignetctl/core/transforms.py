"""Quaternions and rigid transforms, batched over leading dimensions.

Convention (the trajectory format's): a quaternion is (w, x, y, z), unit length, and rotates
object coordinates into world coordinates, so a world vertex is

    world = R(q) · (scale · v) + p.

PyBullet and scipy order quaternions (x, y, z, w); `quat_xyzw_to_wxyz` and
`quat_wxyz_to_xyzw` convert. Every function accepts any leading batch shape, `(..., 4)` for
quaternions and `(..., 3)` for vectors, broadcasting like numpy. Functions that take a
quaternion normalize it first, and a zero quaternion is read as the identity, so no input
makes NaN.
"""

from __future__ import annotations

import numpy as np

IDENTITY_QUATERNION = np.array([1.0, 0.0, 0.0, 0.0])
NORM_FLOOR = 1e-300


def quat_normalize(quaternions):
    """Unit quaternions; a zero quaternion becomes the identity.

    quaternions : (..., 4) float
    returns : (..., 4) float64
    """
    quaternions = np.asarray(quaternions, dtype=np.float64)
    norms = np.linalg.norm(quaternions, axis=-1, keepdims=True)
    is_zero = norms <= NORM_FLOOR
    unit = quaternions / np.where(is_zero, 1.0, norms)
    return np.where(is_zero, IDENTITY_QUATERNION, unit)


def quat_multiply(quaternions_a, quaternions_b):
    """Hamilton product a ⊗ b: the rotation b followed by the rotation a.

    quaternions_a, quaternions_b : (..., 4) float, broadcast against each other
    returns : (..., 4) float64 (not normalized: unit inputs give a unit output)
    """
    a = np.asarray(quaternions_a, dtype=np.float64)
    b = np.asarray(quaternions_b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(quaternions):
    """(w, -x, -y, -z): the inverse rotation of a unit quaternion.

    quaternions : (..., 4) float
    returns : (..., 4) float64
    """
    conjugate = np.array(quaternions, dtype=np.float64, copy=True)
    conjugate[..., 1:] *= -1.0
    return conjugate


def quat_to_matrix(quaternions):
    """Rotation matrices of (normalized) quaternions.

    quaternions : (..., 4) float, w x y z
    returns : (..., 3, 3) float64, proper rotations (R @ v rotates v object-to-world)
    """
    w, x, y, z = np.moveaxis(quat_normalize(quaternions), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def matrix_to_quat(matrices):
    """Quaternions of rotation matrices by Shepperd's method, with w >= 0.

    Of the four algebraically equivalent formulas, each row picks the one whose divisor
    (2|w|, 2|x|, 2|y| or 2|z|) is largest, so the result stays accurate near 180 degrees.

    matrices : (..., 3, 3) float, proper rotations
    returns : (..., 4) float64, unit, w x y z
    """
    m = np.asarray(matrices, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    twice_abs_components = np.sqrt(
        np.maximum(
            0.0,
            np.stack(
                [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22],
                axis=-1,
            ),
        )
    )
    wx, wy, wz = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]
    xy, xz, yz = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    square = twice_abs_components**2
    # Row k holds 4 q_k q: dividing by 2 * (2 |q_k|) gives ±q.
    candidates = np.stack(
        [
            np.stack([square[..., 0], wx, wy, wz], axis=-1),
            np.stack([wx, square[..., 1], xy, xz], axis=-1),
            np.stack([wy, xy, square[..., 2], yz], axis=-1),
            np.stack([wz, xz, yz, square[..., 3]], axis=-1),
        ],
        axis=-2,
    ) / (2.0 * np.maximum(twice_abs_components, 0.1)[..., None])
    best = np.argmax(twice_abs_components, axis=-1)[..., None, None]
    quaternions = quat_normalize(np.take_along_axis(candidates, best, axis=-2)[..., 0, :])
    return np.where(quaternions[..., :1] < 0, -quaternions, quaternions)


def quat_from_axis_angle(axis, angle):
    """Rotation by `angle` radians about `axis` (right-handed); a zero axis gives the identity.

    axis : (..., 3) float, any length
    angle : (...) float, radians
    returns : (..., 4) float64
    """
    axis = np.asarray(axis, dtype=np.float64)
    half_angle = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    norms = np.linalg.norm(axis, axis=-1, keepdims=True)
    unit_axis = np.where(norms > NORM_FLOOR, axis / np.where(norms > NORM_FLOOR, norms, 1.0), 0.0)
    vector_part = np.sin(half_angle) * unit_axis
    scalar_part = np.where(norms > NORM_FLOOR, np.cos(half_angle), 1.0)
    scalar_part = np.broadcast_to(scalar_part, vector_part.shape[:-1] + (1,))
    return np.concatenate([scalar_part, vector_part], axis=-1)


def quat_to_rotation_vector(quaternions):
    """(..., 4) w x y z -> (..., 3) float64 axis · angle, angle in [0, π] (the short way round)."""
    unit = quat_normalize(quaternions)
    unit = np.where(unit[..., :1] < 0, -unit, unit)
    sine = np.linalg.norm(unit[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(sine, unit[..., 0])
    # angle / sin(angle / 2) -> 2 as the angle -> 0
    factor = np.where(sine > 1e-12, angle / np.maximum(sine, 1e-12), 2.0)
    return unit[..., 1:] * factor[..., None]


def quat_from_rotation_vector(rotation_vectors):
    """(..., 3) axis · angle in radians -> (..., 4) float64; zero gives the identity."""
    rotation_vectors = np.asarray(rotation_vectors, np.float64)
    return quat_from_axis_angle(rotation_vectors, np.linalg.norm(rotation_vectors, axis=-1))


def quat_rotate(quaternions, vectors):
    """R(q) · v without building matrices (v + 2w(u×v) + 2u×(u×v), u the vector part).

    quaternions : (..., 4) float
    vectors : (..., 3) float, broadcast against the quaternions' batch shape
    returns : (..., 3) float64
    """
    unit = quat_normalize(quaternions)
    vectors = np.asarray(vectors, dtype=np.float64)
    scalar_part, vector_part = unit[..., :1], unit[..., 1:]
    twice_cross = 2.0 * np.cross(vector_part, vectors)
    return vectors + scalar_part * twice_cross + np.cross(vector_part, twice_cross)


def quat_angle_deg(quaternions_1, quaternions_2):
    """Angle in degrees of the rotation q1⁻¹ q2, in [0, 180].

    q and -q are the same rotation (the result uses |w|), and atan2 instead of acos keeps
    nearly equal inputs finite and accurate.

    quaternions_1, quaternions_2 : (..., 4) float
    returns : (...) float64
    """
    relative = quat_multiply(quat_conjugate(quat_normalize(quaternions_1)), quat_normalize(quaternions_2))
    vector_norm = np.linalg.norm(relative[..., 1:], axis=-1)
    return np.degrees(2.0 * np.arctan2(vector_norm, np.abs(relative[..., 0])))


def random_quaternions(rng, count):
    """Uniformly distributed rotations (Shoemake's subgroup algorithm), w >= 0.

    rng : numpy.random.Generator
    count : int
    returns : (count, 4) float64, unit, w x y z
    """
    u1, u2, u3 = rng.random((3, count))
    root_1, root_2 = np.sqrt(1.0 - u1), np.sqrt(u1)
    quaternions = np.stack(
        [
            root_2 * np.cos(2 * np.pi * u3),
            root_1 * np.sin(2 * np.pi * u2),
            root_1 * np.cos(2 * np.pi * u2),
            root_2 * np.sin(2 * np.pi * u3),
        ],
        axis=-1,
    )
    return np.where(quaternions[:, :1] < 0, -quaternions, quaternions)


def transform_points(vertices, scale, position, quaternion):
    """World coordinates R(q) · (scale · v) + p of object-frame vertices.

    vertices : (V, 3) float (or (..., V, 3), broadcast against the pose batch)
    scale : float or (...) float
    position : (..., 3) float
    quaternion : (..., 4) float, w x y z, object-to-world
    returns : (..., V, 3) float64
    """
    rotations = quat_to_matrix(quaternion)
    scaled = np.asarray(scale, dtype=np.float64)[..., None, None] * np.asarray(vertices, dtype=np.float64)
    rotated = np.einsum("...ij,...vj->...vi", rotations, scaled)
    return rotated + np.asarray(position, dtype=np.float64)[..., None, :]


def quat_xyzw_to_wxyz(quaternions):
    """(x, y, z, w) as PyBullet and scipy write it -> (w, x, y, z).

    quaternions : (..., 4) float
    returns : (..., 4) float64
    """
    quaternions = np.asarray(quaternions, dtype=np.float64)
    return np.concatenate([quaternions[..., 3:], quaternions[..., :3]], axis=-1)


def quat_wxyz_to_xyzw(quaternions):
    """(w, x, y, z) -> (x, y, z, w) as PyBullet and scipy read it.

    quaternions : (..., 4) float
    returns : (..., 4) float64
    """
    quaternions = np.asarray(quaternions, dtype=np.float64)
    return np.concatenate([quaternions[..., 1:], quaternions[..., :1]], axis=-1)


def lowest_vertex_heights(positions, quaternions, scales, hulls):
    """(T, O) height of each object's lowest vertex: min over v of (R(q) · s v)_z + p_z.

    positions : (T, O, 3), quaternions : (T, O, 4) w x y z, scales : (O,),
    hulls : O arrays (H_o, 3) of object-frame vertices (the convex hull's suffice)
    """
    third_rows = quat_to_matrix(quaternions)[..., 2, :]  # (T, O, 3)
    lowest = [
        (third_rows[:, o] @ (scales[o] * np.asarray(hulls[o]).T)).min(axis=1) for o in range(len(hulls))
    ]
    return np.stack(lowest, axis=1) + positions[..., 2]
