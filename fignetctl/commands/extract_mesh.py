"""`fignetctl extract-mesh`: object and environment meshes from a NeRF and prompts, masks or a box."""

from pathlib import Path

import click

from fignetctl.commands import options
from fignetctl.stages import write_summary


@click.command("extract-mesh")
@click.argument("nerf", type=click.Path(dir_okay=False))
@click.option(
    "--cameras",
    "cameras_path",
    type=click.Path(dir_okay=False),
    required=True,
    help="cameras.npz of the views.",
)
@click.option(
    "--images",
    "image_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Image folder.  [default: images/ beside or above cameras.npz]",
)
@click.option(
    "--prompt",
    "prompt_texts",
    multiple=True,
    metavar="VIEW:U,V",
    help="A pixel on the object in a view (image name or index); repeatable, >= 2 views.",
)
@click.option(
    "--prompts",
    "prompts_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="prompts.json (fignetctl.prompts, as render-views writes).",
)
@click.option(
    "--object", "object_name", default=None, help="Which object of --prompts.  [default: the first]"
)
@click.option(
    "--masks",
    "masks_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Folder of user masks: <image stem>.png per view, nonzero = object.",
)
@click.option(
    "--box",
    default=None,
    callback=options.finite_floats(6),
    metavar="X0,Y0,Z0,X1,Y1,Z1",
    help="The object's box V_o in world units, instead of masks.",
)
@click.option(
    "--depth",
    "depth_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="depth.npz (depth (N,H,W), image_names) to use instead of NeRF depth.",
)
@click.option(
    "--resolution",
    type=click.IntRange(8, 512),
    default=96,
    show_default=True,
    help="Grid vertices along the box's longest side.",
)
@click.option(
    "--threshold",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=50.0,
    show_default=True,
    help="Density threshold σ_thr (1 / world unit).",
)
@click.option(
    "--faces",
    type=click.IntRange(min=0, max=10**6),
    default=1000,
    show_default=True,
    help="Faces n_f after decimation (0: none).",
)
@click.option(
    "--padding",
    type=options.FiniteFloatRange(0, 1),
    default=0.1,
    show_default=True,
    help="V_o grows by this fraction of its longest side.",
)
@click.option(
    "--max-size",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=0.25,
    show_default=True,
    help="Largest object extent (world units) for segmentation.",
)
@click.option(
    "--passive-margin",
    type=options.FiniteFloatRange(min=0),
    default=0.1,
    show_default=True,
    help="Environment box: beyond V_o horizontally (world units).",
)
@click.option(
    "--passive-below",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=0.05,
    show_default=True,
    help="Environment box: below the support surface.",
)
@click.option(
    "--passive-above",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Environment box: above the support.  [default: V_o's height]",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder for object.obj, environment.obj, volume.npz, masks/.",
)
@options.device_option
@options.json_option
@options.overwrite_option
def extract_mesh(
    nerf,
    cameras_path,
    image_dir,
    prompt_texts,
    prompts_path,
    object_name,
    masks_dir,
    box,
    depth_path,
    resolution,
    threshold,
    faces,
    padding,
    max_size,
    passive_margin,
    passive_below,
    passive_above,
    output,
    device,
    json_path,
    overwrite,
):
    """Extract an object's mesh and its environment's from NERF (paper, "Mesh Extraction").

    The object is given by point prompts in >= 2 views (masks by GrabCut + NeRF depth), by
    user masks, or by a box. Masked pixels are unprojected with depth to a box V_o; the density
    in V_o is meshed by marching cubes at --threshold, cleaned (small fragments dropped, faces
    outward, the unseen bottom capped) and decimated to --faces. The environment is meshed the
    same way from a box around and below V_o. Writes object.obj (vertices relative to the
    object's origin), environment.obj (world), volume.npz and masks/ into --output; prints the
    folder. See docs/extract-mesh.md.

    \b
    Example:
      fignetctl extract-mesh nerf.pt --cameras capture/ground_truth/cameras.npz \\
          --prompt view_001.png:181,142 --prompt view_006.png:145,143 -o ball
      fignetctl extract-mesh nerf.pt --cameras cameras.npz --prompts capture/prompts.json --object mug -o mug
    """
    from fignetctl.core.mesh_extraction import ExtractionSettings
    from fignetctl.core.object_extraction import ExtractionInputs, run_extraction
    from fignetctl.core.segmentation import SegmentationSettings

    given = [bool(prompt_texts or prompts_path), bool(masks_dir), box is not None]
    if sum(given) != 1:
        raise click.UsageError("give exactly one of --prompt/--prompts, --masks or --box")
    out = Path(output)
    for name in ("object.obj", "environment.obj", "volume.npz"):
        options.output_path(out / name, overwrite)
    json_path = options.json_path_checked(json_path, overwrite)
    settings = ExtractionSettings(
        resolution=resolution,
        threshold=threshold,
        faces=faces,
        padding=padding,
        passive_margin=passive_margin,
        passive_below=passive_below,
        passive_above=passive_above,
    )
    inputs = ExtractionInputs(
        nerf=nerf,
        cameras=cameras_path,
        images=image_dir,
        prompt_texts=list(prompt_texts),
        prompts_json=prompts_path,
        object_name=object_name,
        masks_dir=masks_dir,
        box=box,
        depth=depth_path,
    )
    summary = run_extraction(
        inputs, out, settings, SegmentationSettings(max_size=max_size), options.resolve_device(device)
    )
    agreement = summary["mask_iou"]
    outline = (
        f"; outline vs masks IoU {min(agreement.values()):.2f}-{max(agreement.values()):.2f}"
        if agreement
        else ""
    )
    click.echo(
        f"object: {summary['object_faces']} faces, {summary['object_size']} world units"
        f"{'' if summary['watertight'] else ' (not watertight)'}{outline}; environment: "
        f"{summary['environment_faces']} faces; {summary['seconds']:.1f} s",
        err=True,
    )
    provenance = summary.pop("provenance")
    write_summary(json_path, {"output": str(out), **summary}, provenance)
    click.echo(str(out))
