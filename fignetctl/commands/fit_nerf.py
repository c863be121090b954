"""`fignetctl fit-nerf` and `fignetctl render-nerf`: posed images -> nerf.pt -> PNG views."""

import click

from fignetctl.commands import options
from fignetctl.stages import write_summary


@click.command("fit-nerf")
@click.argument("images_dir", type=click.Path(file_okay=False))
@click.argument("cameras", type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    required=True,
    help="nerf.pt to write; checkpointed while training.",
)
@click.option(
    "--preset",
    type=click.Choice(["fast", "quality"]),
    default="fast",
    show_default=True,
    help="fast: <=200 px images, diffuse colour, 64 -> 192 grid; quality: <=400 px, colour MLP, 64 -> 320.",
)
@click.option(
    "--steps",
    type=click.IntRange(min=1, max=10**7),
    default=None,
    help="Optimiser steps (a resumed run continues to this).  [default: the preset's]",
)
@click.option(
    "--max-image-side",
    type=click.IntRange(min=8, max=8192),
    default=None,
    help="Downscale images so the longer side is at most this.  [default: the preset's]",
)
@click.option(
    "--holdout-every",
    type=click.IntRange(min=0, max=10**5),
    default=None,
    help="Hold out views 0, k, 2k, ... for evaluation (0: none).  [default: 8]",
)
@click.option(
    "--rays-per-batch",
    type=click.IntRange(min=1, max=2**20),
    default=None,
    help="Rays per optimiser step.  [default: the preset's]",
)
@click.option("--resume", is_flag=True, help="Continue the run saved in --output where it stopped.")
@options.seed_option
@options.device_option
@options.rerun_option
@options.json_option
@options.overwrite_option
def fit_nerf(
    images_dir,
    cameras,
    output,
    preset,
    steps,
    max_image_side,
    holdout_every,
    rays_per_batch,
    resume,
    seed,
    device,
    rerun_path,
    json_path,
    overwrite,
):
    """Fit a radiance field to IMAGES_DIR posed by CAMERAS (cameras.npz).

    A dense density grid and a colour-feature grid with a tiny MLP (DVGO-like), empty space
    skipped with an occupancy grid, trained with Adam. Views 0, 8, 16, ... are held out; their
    PSNR is stored in the file and reported on stderr. Prints the path it wrote.

    \b
    Example:
      fignetctl render-views -o capture
      fignetctl fit-nerf capture/images capture/ground_truth/cameras.npz -o nerf.pt --preset fast
      fignetctl render-nerf nerf.pt capture/ground_truth/cameras.npz -o renders --views 0,8
    """
    import torch

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.config import preset_config
    from fignetctl.core.nerf.data import inputs_hash
    from fignetctl.core.nerf.training import finish, make_trainer
    from fignetctl.core.provenance import stamp

    if resume and overwrite:
        raise click.UsageError("--resume continues --output, --overwrite replaces it: give one")
    path = options.output_path(output, overwrite or resume)
    json_path = options.json_path_checked(json_path, overwrite)
    device = options.resolve_device(device)
    if device == "cpu":
        torch.set_num_threads(max(1, min(torch.get_num_threads(), 4)))
    camera_set = read_cameras(cameras)
    config = preset_config(
        preset,
        steps=steps,
        max_image_side=max_image_side,
        holdout_every=holdout_every,
        rays_per_batch=rays_per_batch,
        seed=seed,
    )
    data_hash = inputs_hash(images_dir, cameras)
    trainer = make_trainer(
        images_dir, camera_set, config, device, path if resume and path.exists() else None, data_hash
    )
    trainer.provenance = stamp(images=images_dir, cameras=cameras)
    with options.progress(
        total=trainer.config.steps, initial=trainer.step, unit="step", desc="fit-nerf"
    ) as bar:

        def on_step(record):
            bar.update(1)
            bar.set_postfix(loss=f"{record['loss']:.4g}", psnr=f"{record['psnr']:.2f}")

        trainer.run(path, on_step)
    metrics, renderings = finish(trainer, path)
    click.echo(
        f"held-out PSNR {metrics['held_out_psnr']:.2f} dB over {len(metrics['held_out'])} views, "
        f"{metrics['train_seconds']:.0f} s of training",
        err=True,
    )
    if rerun_path:
        from fignetctl.core.nerf.visualize import log_fit_to_rerun

        log_fit_to_rerun(rerun_path, trainer, renderings)
    write_summary(json_path, {"output": str(path), **metrics}, trainer.provenance)
    click.echo(str(path))


MAX_RENDER_SIDE = 4096  # pixels: as render-views' largest image


@click.command("render-nerf")
@click.argument("nerf", type=click.Path(dir_okay=False))
@click.argument("cameras", type=click.Path(dir_okay=False))
@click.option(
    "-o",
    "--output",
    type=click.Path(file_okay=False),
    required=True,
    help="Folder for <name>.png, <name>_depth.png and <name>_depth.npy.",
)
@click.option(
    "--views", default=None, help="Comma-separated view indices (default: the held-out views, else all)."
)
@click.option(
    "--scale",
    type=options.FiniteFloatRange(min=0, min_open=True),
    default=None,
    help="Image scale against cameras.npz.  [default: the trained size]",
)
@options.device_option
@options.overwrite_option
def render_nerf(nerf, cameras, output, views, scale, device, overwrite):
    """Render colour and depth of views of CAMERAS (cameras.npz) from a fitted NERF.

    Depth is z-depth along each camera's optical axis (0 where nothing is hit): a colour-mapped
    PNG for looking at, and float32 .npy for use. Prints the folder.

    \b
    Example:
      fignetctl render-nerf nerf.pt cameras.npz -o renders --views 0,3
    """
    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.io import load_nerf
    from fignetctl.core.nerf.visualize import render_views_to_folder

    out = options.output_path(output, overwrite)
    camera_set = read_cameras(cameras)
    if scale is not None and max(camera_set.width, camera_set.height) * scale > MAX_RENDER_SIDE:
        raise click.BadParameter(
            f"{scale:g} x {camera_set.width}x{camera_set.height} is over {MAX_RENDER_SIDE} pixels on a side; "
            "lower it",
            param_hint="--scale",
        )
    model = load_nerf(nerf, device=options.resolve_device(device))
    indices = _parse_views(views, len(camera_set), model)
    render_views_to_folder(model, camera_set, indices, out, scale)
    click.echo(str(out))


def _parse_views(text, count, model):
    if text is None:
        held = model.inputs.get("held_out_views") or []
        return [i for i in held if i < count] or list(range(count))
    try:
        indices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise click.BadParameter(
            f"{text!r} is not a comma-separated list of integers", param_hint="--views"
        ) from None
    bad = [i for i in indices if not 0 <= i < count]
    if bad or not indices:
        raise click.BadParameter(
            f"view {bad[0] if bad else text!r} is not in 0..{count - 1}", param_hint="--views"
        )
    return indices
