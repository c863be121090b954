"""`fignetctl rollout`: simulate a scene forward with a learned model."""

import click

from fignetctl.commands import options


@click.command("rollout")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Rollout trajectory file (.h5) to write.")
@click.option("--model", "model_path", default=None, help="Model file from `fignetctl train`, or a bundled one: fignet-star-movi-b, fignet-movi-b.  [default: fignet-star-movi-b]")
@click.option("--steps", type=click.IntRange(min=1), default=100, show_default=True, help="Frames to predict after the scene's first two.")
@click.option("--trajectory", "trajectory_id", default=None, help="Which trajectory of SCENE.  [default: the first]")
@options.device_option
@options.rerun_option
@options.overwrite_option
def rollout(scene, output, model_path, steps, trajectory_id, device, rerun_path, overwrite):
    """Predict --steps frames after the first two frames (t-1, t) of SCENE.

    Writes a trajectory file holding the scene's two frames followed by the predicted ones
    (frame 1 + k is step k). Static objects follow SCENE's frames where it has them. If the
    rollout goes wrong (a non-finite pose, an object flying away), the frames before it are
    still written and the command fails, naming the step and the object.

    \b
    Example:
      fignetctl rollout scene.h5 --steps 200 -o rollout.h5
      fignetctl show rollout.h5 --video rollout.mp4
    """
    from fignetctl.core.model.rollout import RolloutError
    from fignetctl.core.model.runs import load_model, rollout_file

    path = options.output_path(output, overwrite)
    simulator = load_model(model_path, options.resolve_device(device))
    with options.progress(total=steps, unit="step", desc="rollout") as bar:
        try:
            result = rollout_file(simulator, scene, trajectory_id, steps, on_step=lambda _: bar.update(1))
            error = None
        except RolloutError as failure:
            result, error = failure.partial_file, failure
    _write(result, path, rerun_path)
    if error is not None:
        raise click.ClickException(f"{error} (written to {path})")
    click.echo(str(path))


def _write(result, path, rerun_path):
    from fignetctl.core.trajectory import write_trajectories

    write_trajectories(path, result)
    if rerun_path:
        from fignetctl.core.viz import log_trajectory_to_rerun

        log_trajectory_to_rerun(result, next(iter(result.trajectories)), rerun_path)
