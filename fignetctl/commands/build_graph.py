"""`fignetctl build-graph`: extracted meshes + physical properties + a drop -> a 2-frame scene."""

from pathlib import Path

import click

from fignetctl.commands import options
from fignetctl.core.scene_building import ACTIVE, PASSIVE
from fignetctl.stages import write_summary


@click.command("build-graph")
@click.argument("volume_path", metavar="VOLUME", type=click.Path(dir_okay=False))
@click.option(
    "--object",
    "object_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Active mesh.  [default: VOLUME's object_mesh beside it]",
)
@click.option(
    "--environment",
    "environment_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Passive mesh.  [default: VOLUME's environment_mesh]",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    required=True,
    help="Scene trajectory file (.h5) to write.",
)
@click.option(
    "--drop-height",
    type=options.FiniteFloatRange(min=0, max=1000),
    default=0.1,
    show_default=True,
    help="Start this far above the object's rest position (world units).",
)
@click.option(
    "--delta-z",
    type=options.FiniteFloatRange(min=0, max=1000),
    default=0.01,
    show_default=True,
    help="Δz: the history frame is this much higher (fall speed Δz per frame).",
)
@click.option(
    "--start",
    default=None,
    callback=options.finite_floats(3),
    metavar="X,Y,Z",
    help="Start position of the object's origin instead of --drop-height.",
)
@click.option(
    "--velocity",
    default=None,
    callback=options.finite_floats(3),
    metavar="VX,VY,VZ",
    help="Start velocity (world units / s) instead of Δz per frame.",
)
@click.option(
    "--duplicate",
    is_flag=True,
    help="Simulate a copy at the start; the original stays in place as a static object.",
)
@click.option(
    "--active-mass",
    type=options.FiniteFloatRange(min=1e-9, max=1e9),
    default=ACTIVE.mass,
    show_default=True,
)
@click.option(
    "--active-friction",
    type=options.FiniteFloatRange(min=0, max=10),
    default=ACTIVE.friction,
    show_default=True,
)
@click.option(
    "--active-restitution",
    type=options.FiniteFloatRange(min=0, max=1),
    default=ACTIVE.restitution,
    show_default=True,
)
@click.option(
    "--passive-friction",
    type=options.FiniteFloatRange(min=0, max=10),
    default=PASSIVE.friction,
    show_default=True,
)
@click.option(
    "--passive-restitution",
    type=options.FiniteFloatRange(min=0, max=1),
    default=PASSIVE.restitution,
    show_default=True,
)
@click.option(
    "--dt",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=1 / 30,
    show_default="1/30, the bundled models' frame time",
    help="Seconds between frames.",
)
@options.json_option
@options.overwrite_option
def build_graph(
    volume_path,
    object_path,
    environment_path,
    output,
    drop_height,
    delta_z,
    start,
    velocity,
    duplicate,
    active_mass,
    active_friction,
    active_restitution,
    passive_friction,
    passive_restitution,
    dt,
    json_path,
    overwrite,
):
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
    from fignetctl.core.obj import load_obj
    from fignetctl.core.provenance import as_strings, stamp
    from fignetctl.core.scene_building import Properties, build_scene, drop_history
    from fignetctl.core.trajectory import write_trajectories
    from fignetctl.core.volume import read_volume

    path = options.output_path(output, overwrite)
    json_path = options.json_path_checked(json_path, overwrite)
    volume = read_volume(volume_path)
    folder = Path(volume_path).parent
    obj = load_obj(object_path or folder / volume.object_mesh)
    environment = load_obj(environment_path or folder / volume.environment_mesh)
    positions = drop_history(volume.origin, drop_height, delta_z, start, velocity, dt)
    scene = build_scene(
        (obj.vertices, obj.faces),
        (environment.vertices, environment.faces),
        volume.origin,
        positions,
        Properties(active_mass, active_friction, active_restitution),
        Properties(0.0, passive_friction, passive_restitution),
        duplicate,
        volume.environment_origin,
        dt,
    )
    provenance = stamp(
        volume=volume_path,
        object=object_path or folder / volume.object_mesh,
        environment=environment_path or folder / volume.environment_mesh,
    )
    scene.attrs.update(as_strings(provenance))
    write_trajectories(path, scene)
    summary = {
        "output": str(path),
        "object_faces": len(obj.faces),
        "environment_faces": len(environment.faces),
        "start": positions[1],
        "history": positions[0],
    }
    write_summary(json_path, summary, provenance)
    click.echo(
        f"scene: {len(obj.faces)} + {len(environment.faces)} faces, start {positions[1].round(4).tolist()}",
        err=True,
    )
    click.echo(str(path))
