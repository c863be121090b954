"""`fignetctl train`: train FIGNet* (or FIGNet) on a trajectory file, resumably."""

import click

from fignetctl.commands import options
from fignetctl.stages import train as stage

FILE = click.Path(dir_okay=False)


@click.command("train")
@click.argument("dataset", type=FILE)
@click.option(
    "-o", "--output", type=FILE, required=True, help="Model file (.pt), checkpointed while training."
)
@options.settings_options(stage.Settings)
@click.option(
    "--init-from",
    type=FILE,
    help="Start a new run from this model file's weights and normalizer statistics (fine-tuning).",
)
@click.option("--log-csv", type=FILE, help="Also write step, loss, seconds to this CSV at every checkpoint.")
@options.rerun_option
@options.overwrite_option
def train(dataset, output, init_from, log_csv, rerun_path, overwrite, **settings):
    """Train a learned simulator on DATASET (a trajectory file from make-dataset).

    Adam with the learning rate decaying exponentially (--learning-rate, 3e-4 -> 3e-5) over --steps, noise on
    the input history, MSE (or --loss huber) on normalized accelerations of the dynamic mesh nodes. The model
    file is written atomically every --checkpoint-every steps; --resume continues from it with the same
    weights an uninterrupted run would reach (--resume with no --output yet starts the run), and
    --time-limit stops it, checkpointed, with exit code 75 (0 under torchrun). Runs data-parallel
    under torchrun (see docs/simulator.md).

    \b
    Example:
      fignetctl make-dataset --preset movi-b -n 200 --seed 1 -o train.h5
      fignetctl train train.h5 -o model.pt --steps 20000 --workers 1
      fignetctl train train.h5 -o model.pt --steps 20000 --resume   # after an interruption
      fignetctl train train.h5 -o model.pt --steps 20000 --resume --time-limit 9   # exit 75: not done yet
      fignetctl train train.h5 -o tuned.pt --steps 3000 --init-from model.pt --learning-rate 2e-4 2e-5
    """
    from fignetctl.core.model.training import keep_heap_pages

    keep_heap_pages()  # this process trains: its large tensors reuse pages (docs/simulator.md, "Memory")
    replace = overwrite or settings["resume"]  # a resumed run's outputs go on
    path, log_csv = (
        options.output_path(output, replace),
        options.optional_output(log_csv, replace, "--log-csv"),
    )
    rerun_path = options.optional_output(rerun_path, replace, "--rerun")
    settings = options.settings_from(stage.Settings, settings)
    summary = stage.run(dataset, path, settings, init_from, log_csv, rerun_path, overwrite, options.progress)
    if summary["rank"] == 0:
        click.echo(summary["message"], err=True) if summary["stopped_early"] else click.echo(str(path))
    if summary["exit_code"]:
        raise click.exceptions.Exit(summary["exit_code"])
