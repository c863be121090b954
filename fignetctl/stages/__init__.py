"""The stages: one module per command, named as the command (`capture_poses` for
`capture-poses`), between the click shells in `fignetctl.commands` and the library in
`fignetctl.core`.

Each stage exposes

    Settings   a frozen dataclass of the command's settings (every option that is not a path),
               each field declared with `setting(...)`: its default, one line of help and its
               bounds. The command's options are generated from it
               (`fignetctl.commands.options.settings_options`), so a default or a bound is
               written once and holds for the command line and for Python callers alike.
    run(...)   takes the input and output paths and a Settings, writes its outputs atomically
               with their provenance stamp, and returns a summary dict (what `--json` writes).

Stages may name the command's flags in their messages (they are the command's library side);
`fignetctl.core` does not.
"""

from __future__ import annotations

import dataclasses
import math
import typing

from fignetctl.errors import SettingError

DEVICES = ("cpu", "cuda", "auto")


def setting(default, help: str, *, low=None, high=None, low_open=False, choices=None, metavar=None):
    """A Settings field: `default`, one line of `help`, and the bounds the value must lie in
    (`low`, `high`, inclusive unless `low_open`) or the `choices` it must be one of."""
    bounds = {"help": help, "low": low, "high": high, "low_open": low_open, "choices": choices}
    return dataclasses.field(default=default, metadata={**bounds, "metavar": metavar})


def device_setting():
    """The `device` field of every stage that runs torch."""
    return setting("auto", "Torch device; 'auto' uses CUDA when available.", choices=DEVICES)


def sleep_setting(default: bool):
    """`rollout`'s and `evaluate`'s sleeping guard (on by default in `rollout`, off in `evaluate`)."""
    return setting(default, "Stop simulating objects at rest until something comes near (docs/simulator.md).")


def free_flight_setting(default: bool):
    """`rollout`'s and `evaluate`'s free-flight guard."""
    return setting(
        default,
        "Move objects that touch nothing in exact free flight, not by the network (docs/simulator.md).",
    )


def keep_out_setting(default: bool):
    """`rollout`'s and `evaluate`'s keep-out guard."""
    return setting(
        default,
        "Move an object that passed into static geometry back out after each step (docs/simulator.md).",
    )


def rotations_setting():
    """How many turns about gravity `rollout` and `evaluate` average the network over."""
    return setting(
        None,
        "Average the network over this many equal turns of the scene about gravity: exactly equivariant to them, at that many times the network's work (docs/simulator.md).  [default: the model file's, 1 unless it records more]",
        low=1,
        high=64,
    )


def max_faces_setting():
    """The decimation of moving objects' meshes in `rollout` and `evaluate`."""
    return setting(
        None,
        "Decimate each moving object's mesh to at most this many faces; 0 keeps them whole: finer meshes cost time and gain accuracy (docs/accuracy-vs-time.md).  [default: the model file's, 256 for the bundled models]",
        low=0,
        high=10**6,
    )


def check(settings) -> None:
    """Refuse a Settings whose values lie outside their declared bounds (Python callers get the
    command line's checks; a tuple's numbers each, and its length where the annotation fixes
    one): NaN and ±inf are refused for every number."""
    types = field_types(type(settings))
    for field in dataclasses.fields(settings):
        value, meta = getattr(settings, field.name), field.metadata
        if value is None or "help" not in meta:
            continue
        length = _tuple_length(types[field.name])
        if length is not None and (not isinstance(value, (tuple, list)) or len(value) != length):
            raise SettingError(f"{field.name} = {value!r}: give {length} values")
        if meta["choices"] is not None and value not in meta["choices"]:
            raise SettingError(
                f"{field.name} = {value!r}: choose one of {', '.join(map(str, meta['choices']))}"
            )
        for number in value if isinstance(value, (tuple, list)) else (value,):
            if isinstance(number, bool) or not isinstance(number, (int, float)):
                continue
            low, high = meta["low"], meta["high"]
            if (
                not math.isfinite(number)
                or (low is not None and (number <= low if meta["low_open"] else number < low))
                or (high is not None and number > high)
            ):
                raise SettingError(f"{field.name} = {value!r} is outside {_interval(meta)}")


def _tuple_length(hint):
    """The length a `tuple[X, Y, ...]` annotation fixes; None for `tuple[X, ...]` and non-tuples."""
    arguments = typing.get_args(hint)
    if typing.get_origin(hint) is not tuple or Ellipsis in arguments:
        return None
    return len(arguments)


def _interval(meta) -> str:
    low = "-inf" if meta["low"] is None else f"{meta['low']:g}"
    high = "inf" if meta["high"] is None else f"{meta['high']:g}"
    return f"{'(' if meta['low_open'] or meta['low'] is None else '['}{low}, {high}]"


def field_types(settings_class) -> dict:
    """Field name -> its annotated type, with `X | None` reduced to X."""
    hints = typing.get_type_hints(settings_class)
    types = {}
    for name, hint in hints.items():
        arguments = [a for a in typing.get_args(hint) if a is not type(None)]
        types[name] = arguments[0] if type(None) in typing.get_args(hint) and len(arguments) == 1 else hint
    return types


def write_summary(json_path, summary: dict, provenance: dict) -> None:
    """The --json file: `summary` and the output's provenance stamp, written atomically;
    nothing when `json_path` is None."""
    if json_path is None:
        return
    import json

    from fignetctl.core.atomic import atomic_path

    with atomic_path(json_path) as tmp:
        tmp.write_text(json.dumps({**summary, **provenance}, indent=1, default=_plain) + "\n")


def _plain(value):
    """numpy scalars and arrays as json numbers and lists."""
    return value.tolist() if hasattr(value, "tolist") else str(value)


def resolve_device(device: str) -> str:
    """'auto' -> 'cuda' when torch sees a GPU, else 'cpu'; 'cuda' without a GPU is refused."""
    import torch

    if device not in DEVICES:
        raise SettingError(f"`device` {device!r}: choose one of {', '.join(DEVICES)}")
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise SettingError("`device`: CUDA was asked for but torch sees no GPU")
    return device


def no_progress(iterable=None, **kwargs):
    """A progress bar that shows nothing: a stage's bar when its caller gives no `progress`."""
    from tqdm import tqdm

    return tqdm(iterable, **{**kwargs, "disable": True})


def to_stderr(line: str) -> None:
    """A stage's note for the user, one line on stderr (when its caller gives no `report`)."""
    import sys

    print(line, file=sys.stderr, flush=True)
