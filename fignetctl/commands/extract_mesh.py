"""`fignetctl extract-mesh`: object and environment meshes from a NeRF and prompts, masks or a box."""

from pathlib import Path

import click

from fignetctl.commands import options
from fignetctl.stages import extract_mesh as stage


@click.command("extract-mesh")
@click.argument("nerf", type=click.Path(dir_okay=False))
@options.path_option("--cameras", required=True, help="cameras.npz of the views.")
@options.path_option(
    "--images", folder=True, help="Image folder.  [default: images/ beside or above cameras.npz]"
)
@options.path_option("--prompts", help="prompts.json (fignetctl.prompts, as render-views writes).")
@options.path_option(
    "--masks", folder=True, help="Folder of user masks: <image stem>.png per view, nonzero = object."
)
@options.path_option("--depth", help="depth.npz (depth (N,H,W), image_names) to use instead of NeRF depth.")
@options.path_option(
    "-o", "--output", folder=True, required=True, help="Folder for the meshes, volume.npz and masks/."
)
@options.settings_options(
    stage.Settings,
    prompt={"multiple": True, "show_default": False},
    box={"callback": options.finite_floats(6)},
)
@options.json_option
@options.overwrite_option
def extract_mesh(nerf, output, json_path, overwrite, **values):
    """Extract an object's mesh and its environment's from NERF (paper, "Mesh Extraction").

    The object is given by point prompts in >= 2 views (masks by GrabCut + NeRF depth), by
    user masks, or by a box. Masked pixels are unprojected with depth to a box V_o; the density
    in V_o is meshed by marching cubes at --threshold (auto: of a few levels, the one whose
    mesh's outline best matches the masks), cleaned (small fragments dropped, faces outward, the
    unseen bottom capped) and decimated to --faces. The environment is meshed the same way from
    a box around and below V_o. Writes object.obj (vertices relative to the object's origin),
    environment.obj (world), volume.npz and masks/ into --output; prints the folder. See
    docs/extract-mesh.md.

    \b
    Example:
      fignetctl extract-mesh nerf.pt --cameras capture/ground_truth/cameras.npz \\
          --prompt view_001.png:181,142 --prompt view_006.png:145,143 -o ball
      fignetctl extract-mesh nerf.pt --cameras cameras.npz --prompts capture/prompts.json --object mug -o mug
    """
    for name in stage.OUTPUTS:
        options.output_path(Path(output) / name, overwrite)
    json_path = options.optional_output(json_path, overwrite, "--json")
    settings = options.settings_from(stage.Settings, values)
    summary = stage.run(nerf, output, settings, **values, json_path=json_path)
    click.echo(summary["message"], err=True)
    click.echo(str(Path(output)))
