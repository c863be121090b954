"""`fignetctl build-graph`: extracted meshes + physical properties + a drop -> a 2-frame scene."""

import click

from fignetctl.commands import options
from fignetctl.stages import build_graph as stage

FILE = click.Path(dir_okay=False)


@click.command("build-graph")
@click.argument("volume_path", metavar="VOLUME", type=FILE)
@click.option(
    "--object", "object_path", type=FILE, help="Active mesh.  [default: VOLUME's object_mesh beside it]"
)
@click.option(
    "--environment", "environment_path", type=FILE, help="Passive mesh.  [default: VOLUME's environment_mesh]"
)
@click.option("-o", "--output", type=FILE, required=True, help="Scene trajectory file (.h5) to write.")
@options.settings_options(
    stage.Settings,
    start={"callback": options.finite_floats(3)},
    velocity={"callback": options.finite_floats(3)},
    dt={"show_default": "1/30"},
)
@options.json_option
@options.overwrite_option
def build_graph(volume_path, object_path, environment_path, output, json_path, overwrite, **settings):
    """Build the 2-frame scene (t-1, t) that `fignetctl rollout` simulates, from the meshes and
    volume.npz of `extract-mesh` (paper, "Building the Graph").

    The object is active (dynamic), the environment passive (static). Default properties are
    those the bundled models were trained on: active mass 1, friction 0.8, restitution 0.7
    (the paper's FIGNet row), passive friction 0.3, restitution 0.5 (MOVi's floor); the
    paper's FIGNet* row (active 1e-3, 0.5, 0.5; passive 0.5, 0.3) is outside them, and
    `rollout` warns about any value its model was not trained on. The history is a drop: the
    object --drop-height above its rest position, and Δz higher one frame earlier; or --start
    and --velocity. See docs/build-graph.md.

    \b
    Example:
      fignetctl build-graph ball/volume.npz --drop-height 0.1 -o scene.h5
      fignetctl rollout scene.h5 --steps 60 -o rollout.h5
    """
    path = options.output_path(output, overwrite)
    json_path = options.optional_output(json_path, overwrite, "--json")
    settings = options.settings_from(stage.Settings, settings)
    summary = stage.run(volume_path, path, settings, object_path, environment_path, json_path)
    click.echo(summary["message"], err=True)
    click.echo(str(path))
