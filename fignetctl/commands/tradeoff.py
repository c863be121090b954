"""`fignetctl tradeoff`: accuracy against seconds for the knobs that trade one for the other."""

import functools

import click

from fignetctl.commands import options
from fignetctl.stages import tradeoff as stage

_input = functools.partial(options.path_option, exists=True)


@click.command("tradeoff")
@click.argument("knobs", nargs=-1, required=True, type=click.Choice(stage.KNOB_CHOICES))
@options.path_option(
    "-o", "--out-dir", folder=True, required=True, help="Folder for tradeoff-KNOB.json, .csv and .png."
)
@_input(
    "--data",
    help="Ground-truth trajectory file for the simulator knobs.  [default: 8 movi-b trajectories made in OUT_DIR]",
)
@_input(
    "--train-data",
    help="Training file of the message-passing sweep.  [default: 16 movi-b trajectories made in OUT_DIR]",
)
@_input(
    "--capture", folder=True, help="render-views folder (prompts.json, ground_truth/) for marching-cubes."
)
@_input("--nerf", help="nerf.pt of that capture for marching-cubes (fignetctl fit-nerf --preset fast).")
@_input("--nerf-curve", help="Learning-curve json of benchmarks/bench_nerf.py for nerf-steps.")
@options.settings_options(stage.Settings)
@options.overwrite_option
def tradeoff(knobs, out_dir, overwrite, **values):
    """Sweep KNOBS and write, per knob, accuracy against seconds as json, csv and a PNG with
    the Pareto front marked; every point is a median with its quartiles (docs/accuracy-vs-time.md).

    \b
    Knobs: decimation, architecture, collision-radius, message-passing (trains small
    models), marching-cubes (needs --capture and --nerf), nerf-steps, device, rotations;
    or all.

    \b
    Example:
      fignetctl make-dataset --preset movi-b --split test -n 8 --seed 11 -o gt.h5
      fignetctl tradeoff decimation collision-radius --data gt.h5 -o tradeoff/
      fignetctl tradeoff marching-cubes --capture capture --nerf nerf.pt -o tradeoff/
      fignetctl tradeoff nerf-steps --nerf-curve benchmarks/results/nerf_psnr_vs_time.json -o /tmp/t
    """
    settings = options.settings_from(stage.Settings, values)  # values keeps the five input files
    knobs = stage.selected(knobs)
    for knob in knobs:
        for path in stage.output_files(out_dir, knob):
            options.output_path(path, overwrite, "--out-dir")
    stage.run(knobs, out_dir, settings, **values, progress=options.progress, echo=click.echo)
