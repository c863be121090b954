import os
import subprocess
import sys

import pytest
from click.testing import CliRunner

from fignetctl.cli import COMMANDS, cli
from fignetctl.core.containers import require_regular_file
from fignetctl.errors import FormatError


def test_help_lists_every_command_without_importing_heavy_stacks():
    code = (
        "import sys; from click.testing import CliRunner; from fignetctl.cli import cli;"
        "r = CliRunner().invoke(cli, ['--help']); print(r.output);"
        "print('HEAVY', sorted(m for m in ('torch', 'pybullet', 'pycolmap', 'h5py', 'trimesh') if m in sys.modules))"
    )
    output = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    for name in COMMANDS:
        assert name in output
    assert "HEAVY []" in output


def test_every_registered_command_has_help_with_an_example():
    for name in COMMANDS:
        result = CliRunner().invoke(cli, [name, "--help"])
        assert result.exit_code == 0, result.output
        assert "fignetctl " + name in result.output


def test_library_error_becomes_one_line_error(tmp_path):
    result = CliRunner().invoke(cli, ["show", str(tmp_path / "missing.h5")])
    assert result.exit_code != 0
    assert "Traceback" not in result.output
    assert result.output.strip().count("\n") <= 2


def test_progress_in_logs_is_plain_lines_and_can_be_silenced(tmp_path):
    """stderr is not a terminal under CliRunner, as in a batch job's log."""
    from fignetctl.core.trajectory import write_trajectories
    from tests.conftest import box_drop_file

    data = write_trajectories(tmp_path / "b.h5", box_drop_file(frames=6))
    outputs = {}
    for flags in (["--progress", "always"], ["--progress", "never"], ["-q", "--progress", "always"], []):
        video = tmp_path / f"v{len(outputs)}.mp4"
        result = CliRunner().invoke(cli, [*flags, "show", str(data), "--video", str(video)])
        assert result.exit_code == 0, result.output
        outputs[" ".join(flags)] = result.output
    lines = [line for line in outputs["--progress always"].splitlines() if line.startswith("video:")]
    assert lines and lines[-1].startswith("video: 6/6 frame") and "\r" not in outputs["--progress always"]
    for quiet in (
        "--progress never",
        "-q --progress always",
        "",
    ):  # auto: a line every 30 s, and this is quicker
        assert "video:" not in outputs[quiet]


def test_a_missing_training_file_and_a_bad_seed_are_one_line_errors(tmp_path):
    result = CliRunner().invoke(cli, ["train", str(tmp_path / "none.h5"), "-o", str(tmp_path / "m.pt")])
    assert result.exit_code == 1 and result.output.strip() == f"Error: {tmp_path / 'none.h5'}: no such file"
    for seed in ("-1", str(2**32)):
        result = CliRunner().invoke(
            cli, ["make-dataset", "-n", "1", "--seed", seed, "-o", str(tmp_path / "d.h5")]
        )
        assert result.exit_code == 2 and "--seed" in result.output and "0<=x<=4294967295" in result.output
    assert not list(tmp_path.iterdir())


def test_an_operating_system_error_inside_a_command_is_one_line(tmp_path, monkeypatch):
    import errno

    from fignetctl.core import viz
    from fignetctl.core.trajectory import write_trajectories
    from tests.conftest import box_drop_file

    def full_disk(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "v.mp4"))

    monkeypatch.setattr(viz, "render_preview_video", full_disk)
    data = write_trajectories(tmp_path / "b.h5", box_drop_file(frames=3))
    result = CliRunner().invoke(cli, ["show", str(data), "--video", str(tmp_path / "v.mp4")])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.output.strip().splitlines()[-1] == (
        f"Error: {tmp_path / 'v.mp4'}: no space left on device; free some disk space and run it again"
    )


def test_readers_refuse_pipes_and_directories_without_waiting(tmp_path):
    fifo = tmp_path / "pipe.h5"
    os.mkfifo(fifo)
    for args in (
        ["show", str(fifo)],
        ["rollout", str(fifo), "-o", str(tmp_path / "r.h5")],
        ["evaluate", str(fifo)],
        ["capture-poses", "--import-transforms", str(fifo), "-o", str(tmp_path / "c.npz")],
    ):
        result = CliRunner().invoke(cli, args)
        assert result.exit_code != 0 and "Traceback" not in result.output, (args, result.output)
        said = result.output
        assert "not a regular file" in said or "is not a file" in said, (args, said)
    with pytest.raises(FormatError, match="not a regular file"):
        require_regular_file(tmp_path)
    with pytest.raises(FormatError, match="no such model file"):
        require_regular_file(tmp_path / "none.pt", "model")


@pytest.mark.parametrize(
    "error",
    [
        MemoryError(),
        RuntimeError("[enforce fail at alloc_cpu.cpp:119] DefaultCPUAllocator: can't allocate memory"),
        RuntimeError("CUDA out of memory. Tried to allocate 2.00 GiB"),
        "torch",
    ],
)
def test_a_failed_allocation_is_one_line_that_says_what_to_reduce(tmp_path, monkeypatch, error):
    import torch

    from fignetctl.commands import render_views

    def run(*args, **kwargs):
        raise torch.OutOfMemoryError("CUDA error: out of memory") if error == "torch" else error

    monkeypatch.setattr(render_views.stage, "run", run)
    result = CliRunner().invoke(cli, ["render-views", "-o", str(tmp_path / "capture")])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert result.output.strip().splitlines() == [
        "Error: out of memory: try a smaller input, batch, resolution or --rays-per-batch"
    ]


def test_another_runtime_error_is_not_taken_for_memory(tmp_path, monkeypatch):
    from fignetctl.commands import render_views

    def run(*args, **kwargs):
        raise RuntimeError("a bug")

    monkeypatch.setattr(render_views.stage, "run", run)
    result = CliRunner().invoke(cli, ["render-views", "-o", str(tmp_path / "capture")])
    assert isinstance(result.exception, RuntimeError) and str(result.exception) == "a bug"


def test_settings_named_by_the_library_become_flags_on_the_command_line():
    from fignetctl.cli import as_flags

    assert as_flags("use `sim_scale=1`; or `gravity=plane`") == "use --sim-scale 1; or --gravity plane"
    assert as_flags("try another `seed` or more `views`") == "try another --seed or more --views"
    assert as_flags("a file from `fignetctl train`") == "a file from `fignetctl train`"


def test_warnings_logged_by_the_library_name_flags_on_the_command_line(tmp_path):
    """A library warning that names a setting reaches the command line's stderr as its flag."""
    script = (
        "import logging, sys; from fignetctl.cli import cli; "
        "cli.get_command(None, 'show').callback = lambda **kw: logging.getLogger('fignetctl.core.x').warning("
        "'set `threshold` lower, or fit-nerf `region=prompts`'); "
        "sys.argv = ['fignetctl', 'show', 'x.h5']; cli(prog_name='fignetctl')"
    )
    (tmp_path / "x.h5").write_bytes(b"")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=tmp_path)
    assert "set --threshold lower, or fit-nerf --region prompts" in done.stderr, done.stderr


def test_no_library_message_names_a_command_line_flag():
    """fignetctl/core names settings by their Python names; the CLI turns them into flags. Every
    string in core but docstrings is searched for a flag (--name), and no core module parses
    arguments."""
    import ast
    import re
    from pathlib import Path

    import fignetctl

    core = Path(fignetctl.__file__).parent / "core"
    found = []
    for path in core.rglob("*.py"):
        tree = ast.parse(path.read_text())
        docstrings = {  # a string standing alone as a statement documents what it follows
            id(node.value)
            for node in ast.walk(tree)
            if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
        }
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and id(node) not in docstrings
                and re.search(r"(^|[\s(])--[a-z][a-z-]+", node.value)
            ):
                found.append(f"{path.name}:{node.lineno}: {node.value[:80]}")
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [alias.name for alias in node.names] + [getattr(node, "module", None) or ""]
                if {"argparse", "click"} & {name.split(".")[0] for name in names}:
                    found.append(f"{path.name}:{node.lineno}: imports argparse or click")
    assert not found, found


@pytest.mark.parametrize("given", [None, "7"])
def test_the_command_bounds_onednn_primitive_cache_unless_told(monkeypatch, given):
    from fignetctl.cli import ONEDNN_PRIMITIVE_CACHE, main

    if given is None:
        monkeypatch.delenv("ONEDNN_PRIMITIVE_CACHE_CAPACITY", raising=False)
    else:
        monkeypatch.setenv("ONEDNN_PRIMITIVE_CACHE_CAPACITY", given)
    monkeypatch.setattr(sys, "argv", ["fignetctl", "--version"])
    with pytest.raises(SystemExit):
        main()
    assert os.environ["ONEDNN_PRIMITIVE_CACHE_CAPACITY"] == (given or ONEDNN_PRIMITIVE_CACHE)
