"""`fignetctl evaluate`: the paper's metrics of a model against ground truth, with baselines."""

import json

import click

from fignetctl.commands import options
from fignetctl.stages import evaluate as stage


@click.command("evaluate")
@click.argument("data", type=click.Path(dir_okay=False))
@click.option(
    "--model",
    "model_path",
    help="Model file, or a bundled one: fignet-star-movi-b, fignet-movi-b.  [default: fignet-star-movi-b]",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    help="Write the metrics json here (otherwise to stdout).",
)
@options.settings_options(stage.Settings, max_trajectories={"flags": ("-n",)})
@options.overwrite_option
def evaluate(data, model_path, output, overwrite, **settings):
    """Roll out the model from frames 0-1 of every trajectory of DATA and compare.

    Translation RMSE (m) and rotation error (mean and RMS, deg) of the dynamic objects after 50
    steps and at 0.1, 0.2, 0.33, 0.5, 1, 1.67 and 2 seconds, overall, per shape and per motion
    (what the recording does with the object up to then: calm, contact or impact), for the
    model and two baselines: objects that keep their last velocity under gravity and stop at
    the floor, and objects that stand still. The json
    also has the errors at every step ("curves") and the model against each baseline on the
    same objects ("comparison": RMSE ratio and rotation difference with 95 % bootstrap
    intervals over trajectories, and the share of objects the model places closer). By default
    the network moves every object (the paper's figure); --free-flight, --keep-out and --sleep
    evaluate what `rollout` does by default. --ceilings adds PyBullet restarted every frame
    from the model's inputs: the pose and instantaneous velocity (ceiling_velocity) or two
    frames (ceiling_finite_difference), the best any model given that state could do.
    --against MODEL rolls out a second model on the same trajectories, so that "comparison"
    holds the model against it with intervals paired by trajectory (a new model against the
    one it would replace).

    \b
    Example:
      fignetctl make-dataset --preset movi-b --split test -n 20 --seed 99 -o test.h5
      fignetctl evaluate test.h5 -o metrics.json
      fignetctl evaluate test.h5 --with-guards --ceilings -o metrics.json
      fignetctl evaluate test.h5 --model new.pt --against fignet-star-movi-b -o new.json
    """
    path = options.output_path(output, overwrite) if output else None
    metrics = stage.run(
        data, path, options.settings_from(stage.Settings, settings), model_path, options.progress
    )
    click.echo(str(path) if path else json.dumps(metrics, indent=2))
