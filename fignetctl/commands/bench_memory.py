"""`fignetctl bench-memory`: edges, runtime and peak memory of FIGNet and FIGNet* (Table 1)."""

import click

from fignetctl.commands import options
from fignetctl.stages import bench_memory as stage

FILE = click.Path(dir_okay=False)


@click.command("bench-memory")
@click.argument("data", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--model",
    "model_paths",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Model file to measure (repeatable).  [default: untrained FIGNet and FIGNet* with the settings below]",
)
@options.settings_options(stage.Settings)
@click.option(
    "--json", "json_path", type=FILE, help="Write the full results (per pair, method, settings) here."
)
@click.option("--markdown", "markdown_path", type=FILE, help="Also write the markdown tables here.")
@options.overwrite_option
def bench_memory(data, model_paths, json_path, markdown_path, overwrite, **settings):
    """Measure FIGNet and FIGNet* on (trajectory, frame) pairs of each DATA file.

    Per model and file: edges by type (mean ± std), milliseconds per step (graph, network,
    whole step) and per training step (forward + backward), median and IQR, and the peak
    memory of each (MiB; on the CPU from the profiler's allocation events), with the
    FIGNet*/FIGNet ratios beside the paper's (0.35 edges, 0.79 memory, 0.74 time, MOVi-B).
    Frames come from the middle of the trajectories, in contact where possible. The
    markdown tables go to stdout; see docs/bench-memory.md.

    \b
    Example:
      fignetctl make-dataset --preset movi-b --split test -n 10 --seed 5 -o b-test.h5
      fignetctl make-dataset --preset movi-c --split test -n 10 --seed 5 -o c-test.h5
      fignetctl bench-memory b-test.h5 c-test.h5 --json bench.json --markdown bench.md
      fignetctl bench-memory b-test.h5 --model fignet.pt --model fignet-star.pt
    """
    settings = options.settings_from(stage.Settings, settings)
    outputs = {
        f"{flag}_path": options.output_path(path, overwrite, f"--{flag}")
        for flag, path in (("json", json_path), ("markdown", markdown_path))
        if path
    }
    summary = stage.run(data, settings, model_paths, **outputs, progress=options.progress)
    click.echo(summary["markdown"], nl=False)
