"""`nerf.pt`, format `fignetctl.nerf`, format_version 1.

A torch file loaded with `weights_only=True` (nothing is unpickled but tensors and plain values):

    format, format_version, fignetctl_version, inputs_sha256 (provenance.py), config (NerfConfig json), bounds (2x3 list),
    density_shape (X, Y, Z of the density grid), feature_shape (C, X, Y, Z of the colour grid), metrics (json), inputs (json: data hash,
    image size trained on), model (state_dict), training_state (optional: step, optimizer,
    generator state, history, seconds)

Writes are atomic. Anything else raises FormatError in one line.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from fignetctl.core.containers import (
    LOADING_ERRORS,
    read_torch_document,
    weights_do_not_fit,
    write_torch_document,
)
from fignetctl.core.nerf.config import NerfConfig

FORMAT = "fignetctl.nerf"
FORMAT_VERSION = 1


def save_nerf(path, model, metrics=None, inputs=None, training_state=None, provenance=None) -> Path:
    """Write a nerf.pt atomically, stamped with `provenance` (provenance.stamp; default: the
    version alone); `training_state` makes it resumable."""
    fields = {
        "config": model.config.to_json(),
        "bounds": model.bounds.tolist(),
        "density_shape": list(model.field.density_grid.shape[2:]),
        "feature_shape": list(model.field.feature_grid.shape[1:]),
        "metrics": json.dumps(metrics or {}),
        "inputs": json.dumps(inputs or {}),
    }
    return write_torch_document(path, FORMAT, FORMAT_VERSION, model, fields, training_state, provenance)


def read_nerf_payload(path) -> dict:
    """The checked dictionary of a nerf.pt."""
    return read_torch_document(path, "nerf", "nerf.pt", FORMAT, FORMAT_VERSION)


def load_nerf(path, device="cpu", with_training_state=False):
    """nerf.pt -> NerfModel (eval mode) with .render, .render_rays, .density, .bounds, .metrics."""
    from fignetctl.core.nerf.model import NerfModel

    payload = read_nerf_payload(path)
    try:
        config = NerfConfig.from_json(payload["config"])
        bounds = torch.as_tensor(payload["bounds"], dtype=torch.float64)
        if bounds.shape != (2, 3) or not torch.isfinite(bounds).all() or (bounds[1] <= bounds[0]).any():
            raise ValueError(f"bounds {payload['bounds']!r} are not a box (lower, upper)")
        model = NerfModel(config, payload["bounds"])
        shape = tuple(int(s) for s in payload["density_shape"])
        stored = payload["model"]["field.density_grid"].shape
        if tuple(stored) != (1, 1, *shape):
            raise ValueError(f"density_shape {list(shape)} does not match the stored grid {list(stored)}")
        model.field.density_grid = torch.nn.Parameter(torch.zeros(1, 1, *shape))
        model.occupancy.occupied = torch.ones(shape, dtype=torch.bool)
        if "feature_shape" in payload:  # the colour grid may have grown during training
            model.field.feature_grid = torch.nn.Parameter(
                torch.zeros(1, *(int(s) for s in payload["feature_shape"]))
            )
        model.load_state_dict(payload["model"])
        model.metrics = json.loads(payload.get("metrics", "{}"))
        model.inputs = json.loads(payload.get("inputs", "{}"))
    except LOADING_ERRORS as error:
        raise weights_do_not_fit(path, error) from None
    model.to(device).eval()
    if with_training_state:
        return model, payload.get("training_state")
    return model
