"""Model files (`model.pt`): weights, normalizers, settings, and optionally training state.

Layout of the torch file (loaded with `weights_only=True`, so nothing is unpickled but
tensors and plain values):

    format="fignetctl.model", format_version=1, fignetctl_version, simulator_config (json),
    model (state_dict), trained_properties (json, optional: trained_ranges.py), rotations
    (optional int: the turns about gravity its network is averaged over by default), training_state
    (optional: step, optimizer, random states, history, training_config json, data_hash)

Writes are atomic. A file that is not a fignetctl model, a newer format, or weights that do
not fit the stored settings raise FormatError with what to do.
"""

from __future__ import annotations

import dataclasses
import math
from importlib import resources
from pathlib import Path

import numpy as np
import torch

from fignetctl.core.containers import (
    LOADING_ERRORS,
    read_torch_document,
    save_torch_payload,
    weights_do_not_fit,
    write_torch_document,
)
from fignetctl.core.model.simulator import MAX_ROTATIONS, whole_turns
from fignetctl.core.model.trained_ranges import ranges_from_json
from fignetctl.core.provenance import as_strings, file_sha256, stamp
from fignetctl.errors import FormatError, SettingError

FORMAT = "fignetctl.model"
FORMAT_VERSION = 1
DEFAULT_BUNDLED = "fignet-star-movi-b"
BUNDLED = {
    "fignet-star-movi-b": "fignet-star-movi-b.pt",
    "fignet-movi-b": "fignet-movi-b.pt",
}


def bundled_model_path(name=DEFAULT_BUNDLED) -> Path:
    """The path of a checkpoint shipped inside the package."""
    return Path(str(resources.files("fignetctl") / "assets" / "models" / BUNDLED[name]))


RUN_RECORD = ("step", "training_config", "data_hash")
"""What an exported or averaged model keeps of each run's training state, under `provenance`."""


def save_checkpoint(path, simulator, training_state=None, extra=None, provenance=None) -> Path:
    """Write a model file atomically, stamped with `provenance` (provenance.stamp; default: the
    version alone); `training_state` makes it resumable."""
    fields = {"simulator_config": simulator.config.to_json(), **(extra or {})}
    return write_torch_document(path, FORMAT, FORMAT_VERSION, simulator, fields, training_state, provenance)


def read_checkpoint_payload(path) -> dict:
    """The raw, checked dictionary of a model file."""
    return read_torch_document(path, "model", "fignetctl model file", FORMAT, FORMAT_VERSION)


def load_checkpoint(path, with_training_state=False, device="cpu"):
    """Model file -> LearnedSimulator (eval mode), and its training state when asked."""
    payload = read_checkpoint_payload(path)
    simulator = _simulator_from_payload(payload, path)
    simulator.source_sha256 = file_sha256(path)  # outputs made with it record which model file it was
    training_state = payload.get("training_state")
    if with_training_state and training_state is not None and not isinstance(training_state, dict):
        raise FormatError(f"{path}: 'training_state' is not a dictionary; the file cannot be resumed")
    simulator.to(device).eval()
    if with_training_state:
        return simulator, training_state
    return simulator


def _simulator_from_payload(payload, path):
    """A model file's checked dictionary -> LearnedSimulator, or a clear error when its weights
    do not fit its settings or hold NaN or inf."""
    from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig

    try:
        config = SimulatorConfig.from_json(payload["simulator_config"])
        radius = float(config.graph.collision_radius)
        if not (math.isfinite(radius) and radius > 0):
            raise ValueError(f"collision_radius {radius} is not a positive number")
        simulator = LearnedSimulator(config)
        simulator.load_state_dict(payload["model"])
        simulator.trained_properties = ranges_from_json(payload.get("trained_properties"))
    except LOADING_ERRORS as error:
        raise weights_do_not_fit(path, error) from None
    _check_finite_state(simulator, path)
    rotations = payload.get("rotations", 1)
    if not whole_turns(rotations):
        raise FormatError(
            f"{path}: 'rotations' is {rotations!r}, not a whole number of turns from 1 to {MAX_ROTATIONS}"
        )
    simulator.rotations = rotations
    return simulator


def _check_finite_state(simulator, path) -> None:
    """A FormatError naming the first weight or statistic that holds NaN or inf."""
    for name, value in simulator.state_dict().items():
        if value.is_floating_point() and not torch.isfinite(value).all():
            raise FormatError(f"{path}: {name!r} holds NaN or inf; the model cannot be used")


def export_checkpoint(source, destination, trained_on=None, dt=None, gravity=None, rotations=None) -> Path:
    """Copy a model file without its optimiser and random state (a few MB, for shipping).

    What the run was (step, training settings, data hash, loss history) stays, under
    `provenance`, so the shipped file still says how it was made. `trained_on`, the training
    file of a run saved before models stored `trained_properties`, adds them (its hash must
    be the run's), and its time step and gravity. `dt` (s) and `gravity` (3 numbers, m/s²)
    record those of a run saved before models stored them, when its data is not at hand.
    `rotations`: the turns about gravity the model's network is averaged over unless `rollout`
    or `evaluate` say otherwise (simulator.network_acceleration; the default 1, as trained).
    """
    from fignetctl.core.model.simulator import SimulatorConfig
    from fignetctl.core.model.trained_ranges import property_ranges, ranges_to_json, trajectory_largest_sides
    from fignetctl.core.trajectory import read_trajectories

    payload = read_checkpoint_payload(source)
    config = SimulatorConfig.from_json(payload["simulator_config"])
    state = payload.pop("training_state", None)
    if state:  # an exported file keeps the provenance it has
        payload["provenance"] = {key: state[key] for key in (*RUN_RECORD, "history") if key in state}
    if trained_on is not None:
        if file_sha256(trained_on) != payload.get("provenance", {}).get("data_hash"):
            raise FormatError(f"{trained_on}: is not the file {source} was trained on (its hash differs)")
        data = read_trajectories(trained_on)
        sides = np.concatenate([trajectory_largest_sides(data, key) for key in data.trajectories])
        ranges = property_ranges(((t.properties, t.static) for t in data.trajectories.values()), sides)
        payload["trained_properties"] = ranges_to_json(ranges)
        if config.dt is None and config.gravity is None and dt is None and gravity is None:
            dt, gravity = data.dt, data.gravity
    if dt is not None or gravity is not None:
        for name, value in (("dt", config.dt), ("gravity", config.gravity)):
            if value is not None:
                raise FormatError(f"{source}: records its {name} ({value}) already; it is not changed")
        if dt is None or gravity is None:
            raise SettingError("give both the time step and the gravity the model was trained at")
        recorded = dataclasses.replace(config, dt=float(dt), gravity=tuple(float(g) for g in gravity))
        payload["simulator_config"] = recorded.to_json()
    if rotations is not None:
        if not whole_turns(rotations):
            raise SettingError(
                f"rotations must be a whole number from 1 to {MAX_ROTATIONS}, not {rotations!r}"
            )
        payload["rotations"] = rotations
    return save_torch_payload(destination, payload)


class PropertiesDiffer(FormatError):
    """`average_checkpoints` was given files whose trained properties differ and no choice."""


def average_checkpoints(sources, destination, properties_from: int | None = None) -> Path:
    """Average the weights of model files into one, without training state: a "model soup"
    (Wortsman et al. 2022) of runs continued from one model with other seeds, which stay close
    enough in weight space for their mean to be a model too. The normalizer statistics are sums
    and counts, so their mean normalizes with the statistics pooled over the runs. The files
    must share their settings and properties; the result records each one's provenance.
    `properties_from` = k: the files' trained properties may differ (runs on one dataset whose
    properties two versions of the trainer measured differently), and the result takes the
    k-th file's (0-based)."""
    if len(sources) < 2:
        raise SettingError("give two or more model files to average")
    if properties_from is not None and not 0 <= properties_from < len(sources):
        raise SettingError(f"properties_from must be 0 to {len(sources) - 1}, not {properties_from}")
    payloads = [read_checkpoint_payload(source) for source in sources]
    # the weights fit the settings and are finite; settings compare as read, so a field that a
    # file older than it lacks counts as its default
    simulators = [_simulator_from_payload(payload, source) for source, payload in zip(sources, payloads)]
    first, reference = payloads[0], simulators[0]
    advice = "average runs of one model on one dataset"
    for source, simulator in zip(sources[1:], simulators[1:]):
        if simulator.config != reference.config:
            raise FormatError(f"{source}: its simulator_config differ from {sources[0]}'s; {advice}")
        if properties_from is None and simulator.trained_properties != reference.trained_properties:
            raise PropertiesDiffer(
                f"{source}: its trained_properties differ from {sources[0]}'s; {advice} (or, where two"
                " versions of the trainer measured one dataset's properties differently, choose the file"
                " whose properties the mean keeps)"
            )
    weights = {}
    for name, tensor in first["model"].items():
        stacked = torch.stack([payload["model"][name] for payload in payloads])
        mean = stacked.mean(0) if tensor.is_floating_point() else stacked.double().mean(0).round()
        weights[name] = mean.to(tensor.dtype)
    history = [payload.get("training_state") or payload.get("provenance") or {} for payload in payloads]
    fields = {"simulator_config": reference.config.to_json()}
    chosen = payloads[properties_from or 0]
    if "trained_properties" in chosen:
        fields["trained_properties"] = chosen["trained_properties"]
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        **as_strings(stamp(**{f"model_{k}": source for k, source in enumerate(sources)})),
        **fields,
        "model": weights,
        "provenance": {
            "averaged_from": [{key: run[key] for key in RUN_RECORD if key in run} for run in history]
        },
    }
    return save_torch_payload(destination, payload)
