"""The `fignetctl` click group.

Commands are registered by name and imported only when run, so `fignetctl --help`
stays fast (torch, pybullet and pycolmap load inside the commands that use them).
Library errors become one-line click errors here, in one place.
"""

import importlib
import logging
import sys

import click

from fignetctl import __version__
from fignetctl.errors import FignetError, SettingError

# command name -> "module:function" under fignetctl.commands
COMMANDS = {
    "make-dataset": "make_dataset:make_dataset",
    "show": "show:show",
    "train": "train:train",
    "rollout": "rollout:rollout",
    "evaluate": "evaluate:evaluate",
    "bench-memory": "bench_memory:bench_memory",
    "render-views": "render_views:render_views",
    "fit-nerf": "fit_nerf:fit_nerf",
    "render-nerf": "render_nerf:render_nerf",
    "capture-poses": "capture_poses:capture_poses",
    "extract-mesh": "extract_mesh:extract_mesh",
    "build-graph": "build_graph:build_graph",
    "rerender": "rerender:rerender",
    "tradeoff": "tradeoff:tradeoff",
    "import-kubric": "import_kubric:import_kubric",
}

log = logging.getLogger("fignetctl")


class LazyGroup(click.Group):
    """A group that imports a command's module only when that command is used."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        module_name, function = COMMANDS[name].split(":")
        module = importlib.import_module(f"fignetctl.commands.{module_name}")
        return getattr(module, function)

    def format_commands(self, ctx, formatter):
        # Short help without importing every command module.
        rows = [(name, _SUMMARIES.get(name, "")) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except SettingError as error:
            raise click.UsageError(as_flags(str(error))) from None
        except FignetError as error:
            raise click.ClickException(as_flags(str(error))) from None
        except MemoryError:
            raise click.ClickException(OUT_OF_MEMORY) from None
        except RuntimeError as error:  # torch reports a failed allocation as a RuntimeError
            if not is_out_of_memory(error):
                raise
            raise click.ClickException(OUT_OF_MEMORY) from None
        except OSError as error:  # a file the command could not open, read or write
            raise click.ClickException(os_error_sentence(error)) from None


class FlagsFormatter(logging.Formatter):
    """Log lines as the command line reads them: a setting named in backticks becomes its flag."""

    def format(self, record) -> str:
        return as_flags(super().format(record))


def as_flags(message: str) -> str:
    """The library names a setting in backticks by its Python name (`sim_scale`, `gravity=plane`);
    on the command line that is its flag (--sim-scale, --gravity plane)."""
    import re

    def flag(match):
        return "--" + match[1].replace("_", "-") + (f" {match[2]}" if match[2] else "")

    return re.sub(r"`([a-z][a-z0-9_]*)(?:=([^`\s]+))?`", flag, message)


OUT_OF_MEMORY = "out of memory: try a smaller input, batch, resolution or --rays-per-batch"


def is_out_of_memory(error: RuntimeError) -> bool:
    """Whether torch (CPU allocator, CUDA, MPS) failed to allocate memory."""
    text = str(error).lower()
    return type(error).__name__ == "OutOfMemoryError" or any(
        phrase in text for phrase in ("out of memory", "can't allocate memory", "failed to allocate")
    )


def os_error_sentence(error: OSError) -> str:
    """One line for an operating-system error: the file, what went wrong, what to do when clear."""
    import errno

    what = (error.strerror or str(error)).rstrip(".")
    where = f"{error.filename}: " if error.filename else ""
    advice = {
        errno.ENOSPC: "; free some disk space and run it again",
        errno.EACCES: "; check the file's permissions",
    }
    return f"{where}{what[:1].lower()}{what[1:]}{advice.get(error.errno, '')}"


_SUMMARIES = {
    "make-dataset": "Ground-truth trajectories from PyBullet (MOVi-B/C presets).",
    "show": "Summarise a trajectory file; log it to rerun or render an mp4.",
    "train": "Train FIGNet* or FIGNet on a trajectory file (resumable).",
    "rollout": "Simulate a scene forward with a learned model.",
    "evaluate": "Paper metrics of a model against ground truth, with baselines.",
    "bench-memory": "Edges, runtime and peak memory of FIGNet vs FIGNet* (paper Table 1).",
    "render-views": "The bundled capture: a textured tabletop scene rendered from an orbit.",
    "fit-nerf": "Fit a radiance field (nerf.pt) to posed images (cameras.npz).",
    "render-nerf": "Render colour and z-depth PNGs of cameras from a nerf.pt.",
    "capture-poses": "Camera poses (metres, z up) of images or a video: cameras.npz.",
    "extract-mesh": "Object and environment meshes from a NeRF and point prompts: object.obj, volume.npz.",
    "build-graph": "A 2-frame scene (a drop) from extracted meshes, for rollout.",
    "rerender": "A rollout re-rendered through the NeRF by ray bending: PNG frames and an mp4.",
    "import-kubric": "Kubric scenes (metadata.json and the assets' meshes) as a trajectory file.",
    "tradeoff": "Accuracy against seconds for each knob (decimation, radius, ...), Pareto front marked.",
}


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fignetctl")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors: no log lines, no progress.")
@click.option(
    "--progress",
    "progress_mode",
    type=click.Choice(["auto", "always", "never"]),
    default="auto",
    show_default=True,
    help="Progress bars on stderr: redrawn on a terminal; elsewhere (logs of batch jobs) 'auto' writes a line "
    "every 30 s and at the end, 'always' one per second.",
)
def cli(verbose, quiet, progress_mode):
    """fignetctl: photographs to a simulated, re-rendered what-if video.

    Every command reads files and writes files, so stages chain in shell
    pipelines, Makefiles and batch jobs. Logs and progress go to stderr.

    \b
    Example:
      fignetctl make-dataset --preset movi-b -n 8 --seed 1 -o b.h5
      fignetctl show b.h5 --video b.mp4
    """
    from fignetctl.commands.options import set_progress_mode

    set_progress_mode("never" if quiet else progress_mode)
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose + 1, 2)]
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(FlagsFormatter("%(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=level, handlers=[handler])


ONEDNN_PRIMITIVE_CACHE = "64"
"""oneDNN kernels each process keeps (its default is 1024). bf16 training makes new ones for
each new batch shape: with the default a trainer ended 600 steps 0.6 GB larger and trained 18 %
slower (docs/simulator.md, "Memory")."""


def main():
    import os

    # oneDNN reads it when a process first uses it: here, and in the workers, which inherit it
    os.environ.setdefault("ONEDNN_PRIMITIVE_CACHE_CAPACITY", ONEDNN_PRIMITIVE_CACHE)
    cli(prog_name="fignetctl")
