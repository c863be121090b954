"""`fignetctl bench-memory`: edges, runtime and peak memory of FIGNet and FIGNet* (Table 1)."""

import click

from fignetctl.commands import options


@click.command("bench-memory")
@click.argument("data", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@click.option(
    "--model",
    "model_paths",
    multiple=True,
    type=click.Path(exists=True, dir_okay=False),
    help="Model file to measure (repeatable).  [default: untrained FIGNet and FIGNet* with the settings below]",
)
@click.option(
    "--size",
    type=click.Choice(["tiny", "small", "paper"]),
    default=None,
    help="Network size preset of the untrained models.  [default: paper]",
)
@click.option(
    "--max-faces",
    type=click.IntRange(min=0, max=10**6),
    default=None,
    help="Decimate each mesh to at most this many faces; 0 keeps the meshes whole.  [default: 256]",
)
@click.option(
    "--collision-radius",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Face-face edge radius in metres.  [default: 0.2]",
)
@click.option(
    "--samples",
    type=click.IntRange(min=1, max=10**5),
    default=10,
    show_default=True,
    help="(trajectory, frame) pairs per data file.",
)
@click.option(
    "--repeats",
    type=click.IntRange(min=1, max=1000),
    default=5,
    show_default=True,
    help="Timed runs per pair, model and phase, after one warm-up run.",
)
@click.option(
    "--threads",
    type=click.IntRange(min=0, max=1024),
    default=1,
    show_default=True,
    help="Torch CPU threads while measuring; 0 keeps torch's default (all cores).",
)
@click.option(
    "--json",
    "json_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the full results (per pair, method, settings) here.",
)
@click.option(
    "--markdown",
    "markdown_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also write the markdown tables here.",
)
@options.seed_option
@options.device_option
@options.overwrite_option
def bench_memory(
    data,
    model_paths,
    size,
    max_faces,
    collision_radius,
    samples,
    repeats,
    threads,
    json_path,
    markdown_path,
    seed,
    device,
    overwrite,
):
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
    import json

    from fignetctl.bench import memory as benchmark
    from fignetctl.core.atomic import atomic_path
    from fignetctl.core.provenance import stamp

    if model_paths and (size or max_faces is not None or collision_radius):
        raise click.UsageError(
            "--model files carry their own settings: drop --size, --max-faces and --collision-radius"
        )
    outputs = {
        name: options.output_path(path, overwrite, name)
        for name, path in (("--json", json_path), ("--markdown", markdown_path))
        if path
    }
    config = benchmark.BenchmarkConfig(
        samples=samples,
        repeats=repeats,
        seed=seed,
        device=options.resolve_device(device),
        threads=threads or None,
    )
    if model_paths:
        simulators = benchmark.simulators_from_files(model_paths)
    else:
        simulators = benchmark.untrained_simulators(
            size or "paper", collision_radius, 256 if max_faces is None else (max_faces or None), seed
        )
    with options.progress(total=samples * len(data), unit="pair", desc="bench-memory") as bar:
        result = benchmark.run_benchmark(data, simulators, config, on_pair=lambda: bar.update(1))
    result.update(
        stamp(
            **{f"data_{i}": p for i, p in enumerate(data)},
            **{f"model_{i}": p for i, p in enumerate(model_paths)},
        )
    )
    report = benchmark.markdown_report(result)
    for name, text in (("--json", json.dumps(result, indent=1)), ("--markdown", report)):
        if name in outputs:
            with atomic_path(outputs[name]) as tmp:
                tmp.write_text(text)
    click.echo(report, nl=False)
