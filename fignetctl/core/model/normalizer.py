"""Running-statistics normalization of features and targets, as in meshgraphnets.

The statistics are buffers (count, sum, sum of squares, in float64 so that sums over millions
of samples stay exact to ~1e-16 relative), so they are saved and loaded with the model's
`state_dict`. Do not cast a model holding a Normalizer with `.float()` / `.half()`: that casts
the float64 buffers too; `.to(device)` is fine.

The variance is sum_of_squares / count − mean², clamped at 0; it loses precision when
|mean| ≫ std (relative error ~1e-16 · mean² / std²), which the graph's relative features
(velocities, offsets) keep far away. The standard deviation is floored at `std_epsilon`, so a
feature that was constant in every batch seen normalizes to 0 instead of NaN or inf.
"""

from __future__ import annotations

import torch
from torch import nn


class Normalizer(nn.Module):
    """(..., size) -> (..., size): (x − running mean) / max(running std, std_epsilon).

    size : the width of the last axis
    max_accumulations : stop updating the statistics after this many accumulating calls
        (None: never stop)
    std_epsilon : floor of the standard deviation
    """

    def __init__(self, size: int, max_accumulations: int | None = None, std_epsilon: float = 1e-8):
        super().__init__()
        self.size = size
        self.max_accumulations = max_accumulations
        self.std_epsilon = std_epsilon
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("num_accumulations", torch.zeros((), dtype=torch.int64))
        self.register_buffer("sum", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("sum_of_squares", torch.zeros(size, dtype=torch.float64))

    def forward(self, features: torch.Tensor, accumulate: bool) -> torch.Tensor:
        """features : (..., size). With accumulate=True, first add them to the statistics."""
        if accumulate and self.accepts_more_accumulations():
            self.accumulate(features.detach())
        if self.count.item() == 0:
            raise RuntimeError("Normalizer has no statistics yet: call it with accumulate=True first")
        mean, std = self.mean(), self.std()
        return ((features - mean.to(features.dtype)) / std.to(features.dtype)).to(features.dtype)

    def inverse(self, normalized_features: torch.Tensor) -> torch.Tensor:
        """(..., size) -> (..., size): undo forward."""
        mean, std = self.mean(), self.std()
        dtype = normalized_features.dtype
        return normalized_features * std.to(dtype) + mean.to(dtype)

    def accepts_more_accumulations(self) -> bool:
        return self.max_accumulations is None or self.num_accumulations.item() < self.max_accumulations

    @torch.no_grad()
    def accumulate(self, features: torch.Tensor) -> None:
        """Add the rows of features : (..., size) to the running sums."""
        if features.shape[-1] != self.size:
            raise ValueError(f"Normalizer of size {self.size} got features of width {features.shape[-1]}")
        rows = features.reshape(-1, self.size).to(torch.float64)
        self.sum += rows.sum(dim=0)
        self.sum_of_squares += (rows * rows).sum(dim=0)
        self.count += rows.shape[0]
        self.num_accumulations += 1

    def mean(self) -> torch.Tensor:
        """(size,) float64."""
        return self.sum / self.count.clamp(min=1)

    def std(self) -> torch.Tensor:
        """(size,) float64, at least std_epsilon."""
        variance = self.sum_of_squares / self.count.clamp(min=1) - self.mean() ** 2
        return variance.clamp(min=0).sqrt().clamp(min=self.std_epsilon)
