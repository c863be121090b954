"""Options and parameter types shared by the commands, defined once."""

import math
import typing
from pathlib import Path

import click


class FiniteFloatRange(click.FloatRange):
    """click.FloatRange that also refuses NaN and ±inf (FloatRange lets them through: NaN fails
    no comparison, and inf passes a range without a maximum)."""

    name = "finite float range"

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


def finite_floats(count: int, bound: float = 1e6):
    """A click callback parsing `count` comma-separated finite numbers of magnitude at most
    `bound` (a point, a velocity, a box), or None when the option is not given."""

    def parse(ctx, param, value):
        if value is None:
            return None
        try:
            numbers = [float(x) for x in value.split(",")]
        except ValueError:
            numbers = []
        if len(numbers) != count:
            raise click.BadParameter(f"expected {count} comma-separated numbers, got {value!r}")
        if not all(math.isfinite(x) and abs(x) <= bound for x in numbers):
            raise click.BadParameter(f"{value!r}: each number must be finite and within ±{bound:g}")
        return numbers

    return parse


def parsed_by(parse):
    """A click callback: the value as `parse(value)` (a stage's parser) gives it, its
    FignetError a click.BadParameter."""
    from fignetctl.errors import FignetError

    def callback(ctx, param, value):
        try:
            return parse(value)
        except FignetError as error:
            raise click.BadParameter(str(error)) from None

    return callback


json_option = click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write a summary of the result as json (for batch jobs and Makefiles).",
)


def optional_output(path, overwrite: bool, param_name: str):
    """An optional output (--json, --rerun, --log-csv, ...) as a Path, or None when not given;
    refused at the start if it exists without --overwrite."""
    return None if path is None else output_path(path, overwrite, param_name)


overwrite_option = click.option("--overwrite", is_flag=True, help="Replace outputs that already exist.")
rerun_option = click.option(
    "--rerun",
    "rerun_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also log what this command did to a rerun recording (.rrd).",
)


def output_path(path, overwrite, param_name="--output"):
    """Return `path` as a Path; refuse an existing file unless --overwrite was given."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise click.BadParameter(f"{path} exists; pass --overwrite to replace it", param_hint=param_name)
    return path


PROGRESS_MODES = ("auto", "always", "never")
LOG_INTERVAL_SECONDS = 30.0
"""How often a progress line is written when stderr is not a terminal (`--progress auto`)."""
_progress_mode = {"mode": "auto"}


def set_progress_mode(mode: str) -> None:
    """The group's --progress (and -q, which means never) for every bar of this process."""
    if mode not in PROGRESS_MODES:
        raise ValueError(f"unknown progress mode {mode!r}")
    _progress_mode["mode"] = mode


class _LogLines:
    """A stream for tqdm where stderr is not a terminal: each refresh becomes one plain line
    (no carriage returns), so logs of batch jobs show how far a command got."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text):
        text = text.replace("\r", "").strip()
        if text:
            self.stream.write(text + "\n")

    def flush(self):
        self.stream.flush()


def progress(iterable=None, **kwargs):
    """A tqdm progress bar on stderr. On a terminal it redraws in place. Elsewhere it writes
    plain lines: with `--progress auto`, one every LOG_INTERVAL_SECONDS and one at the end, for
    work that takes longer than that; with `--progress always`, one a second from the start.
    `--progress never`, `-q` and disable=True show nothing."""
    import sys

    from tqdm import tqdm

    mode, stream = _progress_mode["mode"], kwargs.pop("file", sys.stderr)
    terminal = hasattr(stream, "isatty") and stream.isatty()
    kwargs.setdefault("dynamic_ncols", terminal)
    if mode == "never" or kwargs.get("disable") is True:
        kwargs["disable"] = True
    elif not terminal:
        stream = _LogLines(stream)
        interval = LOG_INTERVAL_SECONDS if mode == "auto" else 1.0
        kwargs.update(
            disable=False,
            mininterval=interval,
            delay=interval if mode == "auto" else 0.0,
            bar_format="{desc}: {n_fmt}/{total_fmt} {unit} [{elapsed}<{remaining}, {rate_fmt}]{postfix}",
        )
        return _log_bar()(iterable, file=stream, **kwargs)
    return tqdm(iterable, file=stream, **kwargs)


def _log_bar():
    """tqdm whose set_postfix waits for the next line instead of writing one of its own."""
    from tqdm import tqdm

    class LogBar(tqdm):
        def set_postfix(self, ordered_dict=None, refresh=True, **kwargs):
            super().set_postfix(ordered_dict, refresh=False, **kwargs)

    return LogBar


def settings_options(settings_class, **overrides):
    """A decorator adding one option per field of a stage's Settings dataclass (see
    fignetctl.stages): `--field-name`, its default, help and bounds from the field's `setting`.
    bool fields become `--x/--no-x`, int and float fields bounded ranges (floats finite),
    fields with choices a click.Choice. `overrides` maps a field name to what the generator
    cannot know, as click.option arguments that replace the generated ones (a tuple type, a
    callback, multiple=True), and `flags`, more names for it (("-n",))."""
    import dataclasses

    from fignetctl.stages import field_types

    types = field_types(settings_class)
    decorators = []
    for field in dataclasses.fields(settings_class):
        if "help" in field.metadata:
            decorators.append(_settings_option(field, types[field.name], **overrides.get(field.name, {})))

    def decorate(function):
        for decorator in reversed(decorators):
            function = decorator(function)
        return function

    return decorate


def _settings_option(field, kind, flags=(), **changes):
    meta, flag = field.metadata, "--" + field.name.replace("_", "-")
    low, high = meta["low"], meta["high"]
    if meta["choices"] is not None:
        param_type = click.Choice([str(choice) for choice in meta["choices"]])
    elif kind is bool:
        flag = f"{flag}/--no-{field.name.replace('_', '-')}"
        param_type = None
    elif kind is int:
        param_type = click.IntRange(low, high, min_open=meta["low_open"])
    elif kind is float:
        param_type = FiniteFloatRange(low, high, min_open=meta["low_open"])
    elif _float_tuple(kind) and "callback" not in changes:
        param_type = (FiniteFloatRange(low, high, min_open=meta["low_open"]),) * len(typing.get_args(kind))
    else:
        param_type = kind if kind is str else None  # other tuples are parsed by an override
    arguments = {
        "type": param_type,
        "default": field.default,
        "show_default": field.default is not None,
        "metavar": meta["metavar"],
        "help": meta["help"],
    }
    return click.option(*flags, flag, field.name, **{**arguments, **changes})


def _float_tuple(kind) -> bool:
    """A fixed-length tuple of floats (`tuple[float, float]`): each number gets the field's bounds."""
    return typing.get_origin(kind) is tuple and set(typing.get_args(kind)) == {float}


def path_option(*decls, folder=False, exists=False, **kwargs):
    """An option naming a file (or, with `folder`, a folder) that must exist when `exists`."""
    return click.option(
        *decls, type=click.Path(exists=exists, file_okay=not folder, dir_okay=folder), **kwargs
    )


def settings_from(settings_class, values: dict):
    """The Settings of a command from its click arguments: the fields are taken out of
    `values`, which keeps the rest (paths, --overwrite, --json)."""
    import dataclasses

    names = [field.name for field in dataclasses.fields(settings_class)]
    return settings_class(**{name: values.pop(name) for name in names if name in values})
