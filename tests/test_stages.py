"""The stages layer (fignetctl/stages): one stage per command, its Settings the one place for
the command's defaults and bounds, and the command a thin click shell over it."""

import dataclasses
import importlib
import math
import pkgutil
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

import fignetctl.stages
from fignetctl.commands import options
from fignetctl.errors import FignetError
from fignetctl.stages import check, setting

COMMANDS = Path(fignetctl.stages.__file__).parents[1] / "commands"
STAGES = [
    importlib.import_module(f"fignetctl.stages.{info.name}")
    for info in pkgutil.iter_modules(fignetctl.stages.__path__)
]


@dataclasses.dataclass(frozen=True)
class Example:
    count: int = setting(3, "How many.", low=1, high=10)
    scale: float = setting(1.0, "How large.", low=0, low_open=True)
    mode: str = setting("a", "Which.", choices=("a", "b"))
    video: bool = setting(True, "Write a video.")
    limit: float | None = setting(None, "An optional bound.", low=0)
    pair: tuple[float, float] = setting((1.0, 2.0), "Two numbers.", low=0)


@pytest.mark.parametrize(
    "values",
    [
        {"count": 0},
        {"count": 11},
        {"scale": 0.0},
        {"scale": math.nan},
        {"scale": math.inf},
        {"mode": "c"},
        {"pair": (1.0,)},
        {"pair": (1.0, 2.0, 3.0)},
        {"pair": 1.0},
        {"pair": (1.0, math.nan)},
        {"pair": (-1.0, 1.0)},
        {"pair": [1.0, math.nan]},
    ],
)
def test_check_refuses_values_outside_the_declared_bounds(values):
    with pytest.raises(FignetError, match=next(iter(values))):
        check(Example(**values))


def test_check_accepts_the_bounds_and_an_unset_optional():
    check(Example(count=1, scale=1e-9, mode="b", limit=None))
    check(Example(count=10, limit=0.0, pair=(0.0, 5.0)))


def test_the_generated_options_parse_defaults_bounds_flags_and_choices():
    @click.command()
    @options.settings_options(Example)
    def command(**values):
        click.echo(repr(options.settings_from(Example, values)))

    runner = CliRunner()
    assert runner.invoke(command, []).output.strip() == repr(Example())
    given = runner.invoke(
        command, ["--count", "10", "--scale", "2.5", "--mode", "b", "--no-video", "--limit", "3"]
    )
    assert given.output.strip() == repr(Example(count=10, scale=2.5, mode="b", video=False, limit=3.0))
    for bad in (["--count", "11"], ["--scale", "0"], ["--scale", "nan"], ["--mode", "c"], ["--limit", "-1"]):
        assert runner.invoke(command, bad).exit_code == 2, bad
    assert "How many." in runner.invoke(command, ["--help"]).output


@pytest.mark.parametrize("stage", STAGES, ids=lambda module: module.__name__.rsplit(".", 1)[1])
def test_every_stage_has_documented_checked_settings_and_a_run(stage):
    assert dataclasses.is_dataclass(stage.Settings) and stage.Settings.__dataclass_params__.frozen
    for field in dataclasses.fields(stage.Settings):
        assert field.metadata.get("help"), f"{field.name} has no help"
    check(stage.Settings())
    assert callable(stage.run) and stage.run.__doc__
    command = COMMANDS / Path(stage.__file__).name
    assert command.is_file(), f"no command module for {stage.__name__}"
    source = command.read_text()
    assert len(source.splitlines()) <= 60 and f"stages import {stage.__name__.rsplit('.', 1)[1]}" in source
