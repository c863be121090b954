"""Every command on damaged inputs and bad option values (tests/fuzz_corpus.py): each ends in
one error line or a success, never a traceback, a hang or a file left behind."""

import collections

import pytest

from tests.fuzz_corpus import base_files, corpus, run_case


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return base_files(tmp_path_factory.mktemp("fuzz-base"))


def test_bad_files_and_values_end_in_one_error_line(base, tmp_path):
    cases = corpus(flips=2, values=["nan", "-1", "abc", ""])
    results = [run_case(case, base, tmp_path / f"case{i}") for i, case in enumerate(cases)]
    counts = collections.Counter(r["outcome"] for r in results)
    bad = [r for r in results if r["outcome"] not in ("clean", "success")]
    assert not bad, bad[:5]
    assert counts["clean"] >= 0.8 * len(cases)  # damage and bad values are mostly refused


def test_every_command_of_the_corpus_runs_on_the_undamaged_inputs(base, tmp_path):
    """Otherwise its damaged cases would only ever reach the first check that fails."""
    from click.testing import CliRunner

    from fignetctl.cli import cli
    from tests.fuzz_corpus import FILE_COMMANDS

    paths = {slot: str(path) for slot, path in base.items()}
    for index, (command, _) in enumerate(FILE_COMMANDS):
        args = command.format(**paths, out=tmp_path / f"out{index}").split(" ")
        result = CliRunner().invoke(cli, args)
        assert result.exit_code == 0, (command, result.output[-500:])
