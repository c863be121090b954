"""The benchmarks' shared --rotations option."""

import argparse

import pytest

from fignetctl.bench.options import add_rotations_option
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.simulator import MAX_ROTATIONS


def _parser():
    parser = argparse.ArgumentParser(prog="benchmark")
    add_rotations_option(parser)
    return parser


def test_left_out_the_model_file_s_turns_stay():
    """The bundled model records four turns; the option overrides them only when given."""
    assert load_model(rotations=_parser().parse_args([]).rotations).rotations == 4
    assert load_model(rotations=_parser().parse_args(["--rotations", "2"]).rotations).rotations == 2


@pytest.mark.parametrize("wrong", ["0", str(MAX_ROTATIONS + 1), "2.5", "four"])
def test_turns_outside_one_to_the_bound_are_a_usage_error(wrong, capsys):
    with pytest.raises(SystemExit) as exit_info:
        _parser().parse_args(["--rotations", wrong])
    assert exit_info.value.code == 2
    assert f"not a whole number of turns from 1 to {MAX_ROTATIONS}" in capsys.readouterr().err
