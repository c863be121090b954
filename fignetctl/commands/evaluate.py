"""`fignetctl evaluate`: the paper's metrics of a model against ground truth, with baselines."""

import click

from fignetctl.commands import options


@click.command("evaluate")
@click.argument("data", type=click.Path(dir_okay=False))
@click.option(
    "--model",
    "model_path",
    default=None,
    help="Model file, or a bundled one: fignet-star-movi-b, fignet-movi-b.  [default: fignet-star-movi-b]",
)
@click.option(
    "-n",
    "--max-trajectories",
    type=click.IntRange(min=1, max=10**7),
    default=None,
    help="Evaluate only the first N trajectories.",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the metrics json here (otherwise to stdout).",
)
@options.sleep_option(default=False)
@options.free_flight_option(default=False)
@options.keep_out_option(default=False)
@click.option(
    "--with-guards",
    is_flag=True,
    help="Also evaluate the model as `rollout` runs it (free flight, keep-out, sleeping), as the method model_with_guards.",
)
@click.option(
    "--ceilings",
    is_flag=True,
    help="Also evaluate PyBullet restarted every frame from what a model is given (ceiling_velocity, ceiling_finite_difference): what physics allows. DATA must come from make-dataset.",
)
@options.device_option
@options.overwrite_option
def evaluate(
    data,
    model_path,
    max_trajectories,
    output,
    sleep,
    free_flight,
    keep_out,
    with_guards,
    ceilings,
    device,
    overwrite,
):
    """Roll out the model from frames 0-1 of every trajectory of DATA and compare.

    Translation RMSE (m) and rotation error (mean and RMS, deg) of the dynamic objects after 50
    steps and at 0.1, 0.2, 0.33, 0.5, 1, 1.67 and 2 seconds, overall and per shape, for the
    model and two baselines: objects that keep their last velocity under gravity and stop at
    the floor, and objects that stand still. The json
    also has the errors at every step ("curves") and the model against each baseline on the
    same objects ("comparison": RMSE ratio and rotation difference with 95 % bootstrap
    intervals over trajectories, and the share of objects the model places closer). By default
    the network moves every object (the paper's figure); --free-flight, --keep-out and --sleep
    evaluate what `rollout` does by default. --ceilings adds PyBullet restarted every frame
    from the model's inputs: the pose and instantaneous velocity (ceiling_velocity) or two
    frames (ceiling_finite_difference), the best any model given that state could do.

    \b
    Example:
      fignetctl make-dataset --preset movi-b --split test -n 20 --seed 99 -o test.h5
      fignetctl evaluate test.h5 -o metrics.json
      fignetctl evaluate test.h5 --with-guards --ceilings -o metrics.json
    """
    import json

    from fignetctl.core.model.runs import evaluate_file, load_model
    from fignetctl.core.provenance import INPUTS_KEY, stamp

    path = options.output_path(output, overwrite) if output else None
    simulator = load_model(model_path, options.resolve_device(device))
    with options.progress(unit="trajectory", desc="evaluate") as bar:
        metrics = evaluate_file(
            simulator,
            data,
            max_trajectories,
            on_scene=lambda _: bar.update(1),
            sleep=sleep,
            free_flight=free_flight,
            keep_out=keep_out,
            with_guards=with_guards,
            ceilings=ceilings,
        )
    metrics["model"] = str(model_path or "fignet-star-movi-b")
    metrics.update(stamp(data=data))
    metrics[INPUTS_KEY]["model"] = simulator.source_sha256
    text = json.dumps(metrics, indent=2)
    if path is None:
        click.echo(text)
        return
    from fignetctl.core.atomic import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(text)
    click.echo(str(path))
