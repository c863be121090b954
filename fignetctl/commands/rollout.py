"""`fignetctl rollout`: simulate a scene forward with a learned model."""

import click

from fignetctl.commands import options
from fignetctl.stages import rollout as stage

FILE = click.Path(dir_okay=False)


@click.command("rollout")
@click.argument("scene", type=FILE)
@click.option("-o", "--output", type=FILE, required=True, help="Rollout trajectory file (.h5) to write.")
@click.option("--model", help="Model file, or a bundled one: fignet-star-movi-b (default), fignet-movi-b.")
@options.settings_options(
    stage.Settings,
    sim_scale={"callback": options.parsed_by(stage.parse_sim_scale)},
)
@options.rerun_option
@options.json_option
@options.overwrite_option
def rollout(scene, output, model, rerun_path, json_path, overwrite, **settings):
    """Predict --steps frames after the first two frames (t-1, t) of SCENE.

    Writes a trajectory file holding the scene's two frames followed by the predicted ones
    (frame 1 + k is step k). Static objects follow SCENE's frames where it has them. If the
    rollout goes wrong (a non-finite pose, an object flying away), the frames before it are
    still written and the command fails, naming the step and the object.

    A learned model knows the sizes it was trained on: a 10 cm cup is far smaller than the
    bundled models' 1.4-2.8 m objects. By default (--sim-scale auto) such a scene is simulated
    scaled up to their size and mapped back (Froude similarity: the frames come out
    dt / sqrt(scale) apart), and the scale is printed; --sim-scale 1 simulates it as it is.
    A scene under another gravity than the model learned is simulated under the model's, in
    the time that makes it the same motion (the frames come out dt * sqrt(g_model / g_scene)
    apart, and it is printed); one whose gravity points elsewhere is refused.

    \b
    Example:
      fignetctl rollout scene.h5 --steps 200 -o rollout.h5
      fignetctl show rollout.h5 --video rollout.mp4
    """
    path = options.output_path(output, overwrite)
    json_path = options.optional_output(json_path, overwrite, "--json")
    rerun_path = options.optional_output(rerun_path, overwrite, "--rerun")
    settings = options.settings_from(stage.Settings, settings)
    stage.run(scene, path, settings, model, rerun_path, json_path, options.progress)
    click.echo(str(path))
