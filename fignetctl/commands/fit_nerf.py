"""`fignetctl fit-nerf`: posed images -> nerf.pt (render it with `fignetctl render-nerf`)."""

import click

from fignetctl.commands import options
from fignetctl.stages import fit_nerf as stage


@click.command("fit-nerf")
@click.argument("images_dir", type=click.Path(file_okay=False))
@click.argument("cameras", type=click.Path(dir_okay=False))
@options.path_option("-o", "--output", required=True, help="nerf.pt to write; checkpointed while training.")
@options.settings_options(stage.Settings)
@options.rerun_option
@options.json_option
@options.overwrite_option
def fit_nerf(images_dir, cameras, output, rerun_path, json_path, overwrite, **settings):
    """Fit a radiance field to IMAGES_DIR posed by CAMERAS (cameras.npz).

    A dense density grid and a colour-feature grid with a tiny MLP (DVGO-like), empty space
    skipped with an occupancy grid, trained with Adam; finer in --region (e.g. around the objects
    of --prompts). Views 0, 8, 16, ... are held out; their PSNR (and the region's) and the voxel
    size are stored in the file and reported on stderr. Prints the path it wrote.

    \b
    Example:
      fignetctl render-views -o capture
      fignetctl fit-nerf capture/images capture/ground_truth/cameras.npz -o nerf.pt --preset fast
      fignetctl fit-nerf ... -o nerf.pt --prompts capture/prompts.json   # fine voxels around them
      fignetctl render-nerf nerf.pt capture/ground_truth/cameras.npz -o renders --views 0,8
    """
    settings = options.settings_from(stage.Settings, settings)
    path = options.output_path(output, overwrite or settings.resume)
    json_path = options.optional_output(json_path, overwrite, "--json")
    rerun_path = options.optional_output(rerun_path, overwrite, "--rerun")
    summary = stage.run(
        images_dir,
        cameras,
        path,
        settings,
        overwrite=overwrite,
        rerun_path=rerun_path,
        json_path=json_path,
        progress=options.progress,
    )
    click.echo(summary["message"], err=True)
    click.echo(str(path))
