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
    for quiet in ("--progress never", "-q --progress always", ""):  # auto: a line every 30 s, and this is quicker
        assert "video:" not in outputs[quiet]
