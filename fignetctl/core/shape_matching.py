"""Shape matching: the best rigid transform of a rest shape onto predicted points.

The learned simulator predicts a position for every vertex; the object's next pose is the
proper rotation R and translation t minimising

    sum_k w_k |R s_k + t - x_k|²

(Kabsch / Umeyama without scale). With centroids s̄, x̄ (weighted) and the cross-covariance
H = sum_k w_k (s_k - s̄)(x_k - x̄)ᵀ = U Σ Vᵀ, the answer is R = V diag(1, 1, d) Uᵀ with
d = sign det(V Uᵀ), and t = x̄ - R s̄. The sign correction d makes R a rotation, never a
reflection, even for a mirrored target. Everything is computed about the centroids in
float64, so objects far from the origin keep their precision. For planar, collinear or
coincident points the SVD still returns orthonormal U and V, so R is a finite rotation that
fits the points (any rotation about a line is as good as another for collinear points).

`fit_rigid_transform` (numpy) and `fit_rigid_transform_torch` share this contract; both are
batched over leading dimensions. The torch variant runs torch ops on a GPU and hands CPU
tensors to the numpy implementation, which is faster there.
"""

from __future__ import annotations

import numpy as np

# Weights summing to less than this are treated as all-equal weights.
WEIGHT_SUM_FLOOR = 1e-300


def _normalized_weights(weights, point_shape):
    """Weights (..., N) summing to 1; uniform where none are given or they sum to ~0."""
    uniform = np.full(point_shape[:-1], 1.0 / point_shape[-2])
    if weights is None:
        return uniform
    weights = np.broadcast_to(np.asarray(weights, dtype=np.float64), point_shape[:-1])
    totals = weights.sum(axis=-1, keepdims=True)
    usable = totals > WEIGHT_SUM_FLOOR
    return np.where(usable, weights / np.where(usable, totals, 1.0), uniform)


def _determinant_3x3(matrices):
    """(..., 3, 3) -> (...) determinants, written out (cheaper than a batched LU)."""
    m = matrices
    return (
        m[..., 0, 0] * (m[..., 1, 1] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 1])
        - m[..., 0, 1] * (m[..., 1, 0] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 0])
        + m[..., 0, 2] * (m[..., 1, 0] * m[..., 2, 1] - m[..., 1, 1] * m[..., 2, 0])
    )


def _proper_rotation_from_covariance(covariance):
    """R = V diag(1, 1, d) Uᵀ for H = U Σ Vᵀ, d = sign det(V Uᵀ) (d = 1 where det is 0).

    covariance : (..., 3, 3) float64
    returns : (..., 3, 3) float64 with det +1
    """
    u, _, vt = np.linalg.svd(covariance)
    v_ut = np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)
    sign = np.where(_determinant_3x3(v_ut) < 0.0, -1.0, 1.0)
    correction = np.ones(covariance.shape[:-1])
    correction[..., 2] = sign
    return np.swapaxes(vt, -1, -2) @ (correction[..., :, None] * np.swapaxes(u, -1, -2))


def fit_rigid_transform(source, target, weights=None):
    """Proper rotation and translation minimising sum w |R source + t - target|².

    source : (..., N, 3) float, e.g. an object's rest vertices
    target : (..., N, 3) float, e.g. the predicted vertices
    weights : (..., N) float >= 0 or None (uniform); all-zero weights count as uniform
    returns : R (..., 3, 3) float64 with det R = +1, t (..., 3) float64
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    source, target = np.broadcast_arrays(source, target)
    weights = _normalized_weights(weights, source.shape)
    source_centroid = (weights[..., None, :] @ source)[..., 0, :]
    target_centroid = (weights[..., None, :] @ target)[..., 0, :]
    weighted_source = source - source_centroid[..., None, :]
    weighted_source *= weights[..., :, None]  # in place: these arrays are the big ones
    covariance = np.swapaxes(weighted_source, -1, -2) @ (target - target_centroid[..., None, :])
    rotation = _proper_rotation_from_covariance(covariance)
    translation = target_centroid - (rotation @ source_centroid[..., :, None])[..., 0]
    return rotation, translation


def _normalized_weights_torch(torch, weights, point_shape, like):
    """Torch twin of _normalized_weights, in float64 on `like`'s device."""
    uniform = torch.full(point_shape[:-1], 1.0 / point_shape[-2], dtype=torch.float64, device=like.device)
    if weights is None:
        return uniform
    weights = torch.as_tensor(weights, dtype=torch.float64, device=like.device).expand(point_shape[:-1])
    totals = weights.sum(dim=-1, keepdim=True)
    usable = totals > WEIGHT_SUM_FLOOR
    return torch.where(usable, weights / torch.where(usable, totals, torch.ones_like(totals)), uniform)


def _proper_rotation_from_covariance_torch(torch, covariance):
    """Torch twin of _proper_rotation_from_covariance (float64 in, float64 out)."""
    u, _, vt = torch.linalg.svd(covariance)
    v, ut = vt.transpose(-1, -2), u.transpose(-1, -2)
    sign = torch.where(_determinant_3x3(v @ ut) < 0.0, -1.0, 1.0).to(covariance.dtype)
    correction = torch.ones(covariance.shape[:-1], dtype=covariance.dtype, device=covariance.device)
    correction[..., 2] = sign
    return v @ (correction[..., :, None] * ut)


def _fit_rigid_transform_torch_native(torch, source, target, weights):
    """fit_rigid_transform in torch ops, float64 throughout, on the tensors' device."""
    source, target = torch.broadcast_tensors(source.to(torch.float64), target.to(torch.float64))
    weights = _normalized_weights_torch(torch, weights, source.shape, source)
    source_centroid = (weights[..., None, :] @ source)[..., 0, :]
    target_centroid = (weights[..., None, :] @ target)[..., 0, :]
    weighted_source = (source - source_centroid[..., None, :]) * weights[..., :, None]
    covariance = weighted_source.transpose(-1, -2) @ (target - target_centroid[..., None, :])
    rotation = _proper_rotation_from_covariance_torch(torch, covariance)
    translation = target_centroid - (rotation @ source_centroid[..., :, None])[..., 0]
    return rotation, translation


def fit_rigid_transform_torch(source, target, weights=None):
    """`fit_rigid_transform` for torch tensors, batched, on the tensors' device.

    Computed in float64 (centroids, covariance, SVD) and returned in the dtype of
    torch.promote_types(source, target) (float32 stays float32 for the rollout). Not meant for
    backpropagation. CPU tensors go through the numpy implementation (zero-copy, and several
    times faster than torch's CPU kernels on (..., N, 3) arrays); other devices use torch ops.

    source : (..., N, 3) tensor; target : (..., N, 3) tensor; weights : (..., N) tensor or None
    returns : R (..., 3, 3) with det R = +1, t (..., 3)
    """
    import torch

    output_dtype = torch.promote_types(source.dtype, target.dtype)
    if not output_dtype.is_floating_point:
        output_dtype = torch.float64
    if source.device.type == "cpu" and target.device.type == "cpu":
        numpy_weights = None if weights is None else torch.as_tensor(weights).detach().cpu().numpy()
        numpy_points = source.detach().numpy(), target.detach().numpy()
        rotation, translation = fit_rigid_transform(*numpy_points, numpy_weights)
        rotation, translation = torch.from_numpy(rotation), torch.from_numpy(translation)
    else:
        rotation, translation = _fit_rigid_transform_torch_native(torch, source, target, weights)
    return rotation.to(output_dtype), translation.to(output_dtype)
