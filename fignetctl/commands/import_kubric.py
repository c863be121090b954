"""`fignetctl import-kubric`: Kubric scenes (metadata.json) as a trajectory file."""

import click

from fignetctl.commands import options


@click.command("import-kubric")
@click.argument("metadata", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--assets",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder of the assets' collision meshes: <asset_id>/collision_geometry.obj (Kubric's layout), "
    "<asset_id>.obj or <asset_id>/<asset_id>.obj.",
)
@click.option("-o", "--output", type=click.Path(dir_okay=False), required=True, help="Trajectory file (.h5).")
@click.option("--floor-friction", type=options.FiniteFloatRange(0, 10), default=0.3, show_default=True)
@click.option("--floor-restitution", type=options.FiniteFloatRange(0, 1), default=0.5, show_default=True)
@click.option(
    "--floor-size",
    type=options.FiniteFloatRange(0.01, 1e4),
    default=20.0,
    show_default=True,
    help="Side of the floor square (m).",
)
@options.overwrite_option
def import_kubric(metadata, assets, output, floor_friction, floor_restitution, floor_size, overwrite):
    """Convert Kubric scenes (each a MOVi-style worker's metadata.json) into one trajectory file:
    one trajectory per scene, the instances with their asset's collision mesh, scale, mass,
    friction, restitution, poses and velocities at every frame, and a static floor at z = 0
    (Kubric keeps its floor out of the instances). See docs/formats.md.

    \b
    Example:
      fignetctl import-kubric movi/*/metadata.json --assets kubasic/ -o movi.h5
      fignetctl show movi.h5
      fignetctl evaluate movi.h5 -o metrics.json
    """
    from fignetctl.core.kubric import kubric_file
    from fignetctl.core.provenance import as_strings, stamp
    from fignetctl.core.trajectory import write_trajectories

    path = options.output_path(output, overwrite)
    data = kubric_file(list(metadata), assets, floor_friction, floor_restitution, floor_size / 2)
    data.attrs.update(
        as_strings(stamp(**{f"metadata_{i}": p for i, p in enumerate(metadata)}, assets=assets))
    )
    write_trajectories(path, data)
    objects = sum(t.num_objects - 1 for t in data.trajectories.values())
    click.echo(f"{len(data.trajectories)} scenes, {objects} objects, {1 / data.dt:g} frames/s", err=True)
    click.echo(str(path))
