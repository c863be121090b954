"""`nerf.pt`, format `fignetctl.nerf`, format_version 1 or 2.

A torch file loaded with `weights_only=True` (nothing is unpickled but tensors and plain values):

    format, format_version, fignetctl_version, inputs_sha256 (provenance.py), config (NerfConfig json), bounds (2x3 list),
    density_shape (X, Y, Z of the density grid), feature_shape (C, X, Y, Z of the colour grid), metrics (json), inputs (json: data hash,
    image size trained on), model (state_dict), training_state (optional: step, optimizer,
    generator state, history, seconds)

Version 2 (a field fitted in a region, fit-nerf --region) adds `region` (2x3 list: the box of
the fine grids), `region_density_shape` and `region_feature_shape`, and the weights
`field.region_density_grid`, `field.region_feature_grid`, `occupancy.region_occupied`. A field
without a region is written as version 1, so older fignetctl reads it; version 1 files load as
before. Writes are atomic. Anything else raises FormatError in one line.
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
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)


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
    version = 1
    if model.field.has_region:
        version = FORMAT_VERSION
        fields["region"] = model.region.tolist()
        fields["region_density_shape"] = list(model.field.region_density_grid.shape[2:])
        fields["region_feature_shape"] = list(model.field.region_feature_grid.shape[1:])
    return write_torch_document(path, FORMAT, version, model, fields, training_state, provenance)


def read_nerf_payload(path) -> dict:
    """The checked dictionary of a nerf.pt."""
    return read_torch_document(path, "nerf", "nerf.pt", FORMAT, READABLE_VERSIONS)


def load_nerf(path, device="cpu", with_training_state=False):
    """nerf.pt -> NerfModel (eval mode) with .render, .render_rays, .density, .bounds, .metrics."""
    from fignetctl.core.nerf.model import NerfModel

    payload = read_nerf_payload(path)
    try:
        config = NerfConfig.from_json(payload["config"])
        bounds = _box(payload["bounds"], "bounds")
        region = None
        if payload.get("format_version") == 2:
            region = _box(payload["region"], "region")
            if (region[0] < bounds[0] - 1e-5).any() or (region[1] > bounds[1] + 1e-5).any():
                raise ValueError(f"region {payload['region']!r} is not inside bounds {payload['bounds']!r}")
        model = NerfModel(
            config, payload["bounds"], region=payload.get("region") if region is not None else None
        )
        grids = [("density_grid", "density_shape", "feature_grid", "feature_shape", "occupied")]
        if region is not None:
            grids.append(
                (
                    "region_density_grid",
                    "region_density_shape",
                    "region_feature_grid",
                    "region_feature_shape",
                    "region_occupied",
                )
            )
        for density, density_shape, features, feature_shape, occupied in grids:
            shape = tuple(int(s) for s in payload[density_shape])
            stored = payload["model"][f"field.{density}"].shape
            if tuple(stored) != (1, 1, *shape):
                raise ValueError(
                    f"{density_shape} {list(shape)} does not match the stored grid {list(stored)}"
                )
            setattr(model.field, density, torch.nn.Parameter(torch.zeros(1, 1, *shape)))
            setattr(model.occupancy, occupied, torch.ones(shape, dtype=torch.bool))
            if feature_shape in payload:  # the colour grid may have grown during training
                setattr(
                    model.field,
                    features,
                    torch.nn.Parameter(torch.zeros(1, *(int(s) for s in payload[feature_shape]))),
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


def _box(value, name) -> torch.Tensor:
    box = torch.as_tensor(value, dtype=torch.float64)
    if box.shape != (2, 3) or not torch.isfinite(box).all() or (box[1] <= box[0]).any():
        raise ValueError(f"{name} {value!r} are not a box (lower, upper)")
    return box
