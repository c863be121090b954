"""`fignetctl rollout`: simulate a scene forward with a learned model."""

import math

import click

from fignetctl.commands import options
from fignetctl.stages import write_summary


@click.command("rollout")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    required=True,
    help="Rollout trajectory file (.h5) to write.",
)
@click.option(
    "--model",
    "model_path",
    default=None,
    help="Model file from `fignetctl train`, or a bundled one: fignet-star-movi-b, fignet-movi-b.  [default: fignet-star-movi-b]",
)
@click.option(
    "--steps",
    type=click.IntRange(min=1, max=10**6),
    default=100,
    show_default=True,
    help="Frames to predict after the scene's first two.",
)
@click.option(
    "--trajectory", "trajectory_id", default=None, help="Which trajectory of SCENE.  [default: the first]"
)
@click.option(
    "--sim-scale",
    default="auto",
    show_default=True,
    callback=lambda ctx, param, value: _sim_scale(value),
    help="Simulate the scene scaled by this factor, or 'auto': a scene whose largest moving object is outside "
    "the sizes the model was trained on (recorded in the model file; 1.4-2.8 m for the bundled ones) is "
    "brought to their median size (2.1 m), others are left as they are. Scaled frames come back "
    "dt / sqrt(scale) apart.",
)
@options.sleep_option(default=True)
@options.free_flight_option(default=True)
@options.keep_out_option(default=True)
@options.device_option
@options.rerun_option
@options.json_option
@options.overwrite_option
def rollout(
    scene,
    output,
    model_path,
    steps,
    trajectory_id,
    sim_scale,
    sleep,
    free_flight,
    keep_out,
    device,
    rerun_path,
    json_path,
    overwrite,
):
    """Predict --steps frames after the first two frames (t-1, t) of SCENE.

    Writes a trajectory file holding the scene's two frames followed by the predicted ones
    (frame 1 + k is step k). Static objects follow SCENE's frames where it has them. If the
    rollout goes wrong (a non-finite pose, an object flying away), the frames before it are
    still written and the command fails, naming the step and the object.

    A learned model knows the sizes it was trained on: a 10 cm cup is far smaller than the
    bundled models' 1.4-2.8 m objects. By default (--sim-scale auto) such a scene is simulated
    scaled up to their size and mapped back (Froude similarity: the frames come out
    dt / sqrt(scale) apart), and the scale is printed; --sim-scale 1 simulates it as it is.

    \b
    Example:
      fignetctl rollout scene.h5 --steps 200 -o rollout.h5
      fignetctl show rollout.h5 --video rollout.mp4
    """
    from fignetctl.core.model.rollout import RolloutError
    from fignetctl.core.model.runs import load_model, rollout_file
    from fignetctl.core.provenance import from_strings

    path = options.output_path(output, overwrite)
    json_path = options.json_path_checked(json_path, overwrite)
    simulator = load_model(model_path, options.resolve_device(device))
    with options.progress(total=steps, unit="step", desc="rollout") as bar:
        try:
            result = rollout_file(
                simulator,
                scene,
                trajectory_id,
                steps,
                on_step=lambda _: bar.update(1),
                sim_scale=sim_scale,
                sleep=sleep,
                free_flight=free_flight,
                keep_out=keep_out,
            )
            error = None
        except RolloutError as failure:
            result, error = failure.partial_file, failure
    _write(result, path, rerun_path)
    scale = float(result.attrs["sim_scale"])
    if scale != 1.0:
        click.echo(
            f"simulated at {scale:.4g}x its size, as the model knows objects of that size; "
            f"frames {1000 * result.dt:.3g} ms apart (--sim-scale 1 to simulate it as it is)",
            err=True,
        )
    trajectory = next(iter(result.trajectories.values()))
    summary = {
        "output": str(path),
        "steps": trajectory.num_frames - 2,
        "sim_scale": scale,
        "frame_seconds": float(result.dt),
        "final_positions": trajectory.positions[-1][~trajectory.static],
        "error": None if error is None else str(error),
    }
    write_summary(json_path, summary, from_strings(result.attrs))
    if error is not None:
        raise click.ClickException(f"{error} (written to {path})")
    click.echo(str(path))


def _sim_scale(value):
    if value.strip().lower() == "auto":
        return "auto"
    try:
        scale = float(value)
    except ValueError:
        scale = float("nan")
    if not (math.isfinite(scale) and 1e-3 <= scale <= 1e3):
        raise click.BadParameter(f"{value!r} is not 'auto' or a scale between 0.001 and 1000")
    return scale


def _write(result, path, rerun_path):
    from fignetctl.core.trajectory import write_trajectories

    write_trajectories(path, result)
    if rerun_path:
        from fignetctl.core.viz import log_trajectory_to_rerun

        log_trajectory_to_rerun(result, next(iter(result.trajectories)), rerun_path)
