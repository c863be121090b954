import subprocess
import sys

from click.testing import CliRunner

from fignetctl.cli import COMMANDS, cli


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
