"""fit-nerf: posed images (a folder and cameras.npz) -> a radiance field, nerf.pt."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.core.rerun_log import DEFAULT_VIEWER
from fignetctl.errors import SettingError
from fignetctl.stages import (
    check,
    device_setting,
    no_progress,
    resolve_device,
    setting,
    to_stderr,
    write_summary,
)


@dataclasses.dataclass(frozen=True)
class Settings:
    preset: str = setting(
        "fast",
        "fast: <=200 px images, diffuse colour, 64 -> 192 grid; quality: <=400 px, colour MLP, 64 -> 320.",
        choices=("fast", "quality"),
    )
    steps: int | None = setting(
        None, "Optimiser steps (a resumed run continues to this).  [default: the preset's]", low=1, high=10**7
    )
    max_image_side: int | None = setting(
        None,
        "Downscale images so the longer side is at most this.  [default: the preset's]",
        low=8,
        high=8192,
    )
    holdout_every: int | None = setting(
        None, "Hold out views 0, k, 2k, ... for evaluation (0: none).  [default: 8]", low=0, high=10**5
    )
    rays_per_batch: int | None = setting(
        None, "Rays per optimiser step.  [default: the preset's]", low=1, high=2**20
    )
    background: str | None = setting(
        None,
        "What rays see past the scene box: environment (a learned colour per direction, for walls "
        "or sky beyond the box), learned (one colour), white, black, or auto (environment when a "
        "fifth of the sparse points lie outside the scene box, a capture in a room; else learned).  "
        "[default: the preset's, auto]",
        choices=("auto", "environment", "learned", "white", "black"),
    )
    near: float | None = setting(
        None,
        "Rays start this fraction of the cameras' distance to what they look at from their camera, "
        "so no camera hides fog right in front of itself.  [default: the preset's: 0.2 for a capture "
        "in a room (as --background auto tells it), else 0]",
        low=0,
        high=0.9,
    )
    distortion: float | None = setting(
        None,
        "Weight of the distortion loss, which gathers each ray's weight onto one surface instead of "
        "fog along it; 0: off.  [default: the preset's: fast 0.03, quality 0]",
        low=0,
        high=10,
    )
    region: str = setting(
        "auto",
        "Where to fit finely: scene (one grid over the scene box), prompts (around the objects of "
        "--prompts), support:H (the support plane z = 0's extent, H high), a box X0,Y0,Z0,X1,Y1,Z1, "
        "or auto (prompts with --prompts, else scene). The rest of the scene gets a coarse grid.",
        metavar="auto|scene|prompts|support:H|BOX",
    )
    prompts: str | None = setting(
        None, "prompts.json (render-views writes one) for --region prompts/auto.", metavar="PROMPTS.json"
    )
    region_margin: float = setting(
        0.12,
        "--region prompts: half-size of the cube around each prompted object (world units).",
        low=0,
        low_open=True,
    )
    region_rays: float = setting(
        0.0,
        "With a region: this share of each batch is drawn from the rays that pass through it, so a "
        "region that fills a small part of the images is trained as often as the rest (a tabletop "
        "in a room: 0.5).",
        low=0,
        high=1,
    )
    resume: bool = setting(False, "Continue the run saved in --output where it stopped.")
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    device: str = device_setting()
    rerun_connect: str | None = setting(
        None,
        "Stream loss and PSNR per step, then the held-out renders, to the rerun viewer at ADDR while "
        f"the fit runs (a viewer started with `rerun`: {DEFAULT_VIEWER}); a warning if none listens.",
        metavar="ADDR",
    )


def run(
    images_dir,
    cameras,
    output,
    settings: Settings = Settings(),
    *,
    overwrite=False,
    rerun_path=None,
    json_path=None,
    progress=None,
    report=None,
) -> dict:
    """Fit a radiance field to the images in `images_dir` posed by `cameras` (cameras.npz) and
    write it to `output` (nerf.pt, checkpointed while training; with `settings.resume`, the run
    saved there is continued). `progress` makes the step bar (a tqdm-like factory; none shown
    when None). Optionally a rerun recording, the same streamed to the viewer at
    `settings.rerun_connect` as the fit goes (a warning through `report`, stderr when None, if
    none listens), and the --json summary. `settings.region` chooses where the field is fitted
    finely (core/nerf/region.py). Returns the summary (output and the metrics stored in nerf.pt:
    held-out PSNR, on the region too, voxel sizes) with a one-line `message`."""
    import torch

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.config import preset_config
    from fignetctl.core.nerf.data import inputs_hash
    from fignetctl.core.nerf.region import parse_region
    from fignetctl.core.nerf.training import finish, make_trainer
    from fignetctl.core.nerf.visualize import log_fit_step, log_held_out
    from fignetctl.core.provenance import stamp
    from fignetctl.core.rerun_log import live_recording, viewer_address

    check(settings)
    region = parse_region(settings.region, settings.prompts, settings.region_margin)
    if settings.rerun_connect is not None:
        viewer_address(settings.rerun_connect)  # a bad address is refused before the fit, not after
    if settings.resume and overwrite:
        raise SettingError("--resume continues --output, --overwrite replaces it: give one")
    path = Path(output)
    device = resolve_device(settings.device)
    if device == "cpu":
        torch.set_num_threads(max(1, min(torch.get_num_threads(), 4)))
    camera_set = read_cameras(cameras)
    config = preset_config(
        settings.preset,
        steps=settings.steps,
        max_image_side=settings.max_image_side,
        holdout_every=settings.holdout_every,
        rays_per_batch=settings.rays_per_batch,
        background=settings.background,
        near_fraction=settings.near,
        distortion_weight=settings.distortion,
        region_rays=settings.region_rays,
        seed=settings.seed,
    )
    data_hash = inputs_hash(images_dir, cameras)
    resume_from = path if settings.resume and path.exists() else None
    trainer = make_trainer(images_dir, camera_set, config, device, resume_from, data_hash, region)
    trainer.provenance = stamp(images=images_dir, cameras=cameras)
    _report_capture(trainer, settings, report or to_stderr)
    with live_recording(settings.rerun_connect, rerun_path or path, report or to_stderr) as live:
        with (progress or no_progress)(
            total=trainer.config.steps, initial=trainer.step, unit="step", desc="fit-nerf"
        ) as bar:

            def on_step(record):
                bar.update(1)
                bar.set_postfix(loss=f"{record['loss']:.4g}", psnr=f"{record['psnr']:.2f}")
                if live:
                    log_fit_step(*live, record)

            trainer.run(path, on_step)
        metrics, renderings = finish(trainer, path)
        if live:
            log_held_out(*live, trainer, renderings)
    message = _message(metrics)
    if rerun_path:
        from fignetctl.core.nerf.visualize import log_fit_to_rerun

        log_fit_to_rerun(rerun_path, trainer, renderings)
    summary = {
        "output": str(path),
        **metrics,
        "background": trainer.config.background,
        "near_fraction": trainer.config.near_fraction,
    }
    write_summary(json_path, summary, trainer.provenance)
    return {**summary, "message": message}


def _report_capture(trainer, settings: Settings, report) -> None:
    """Say so when the preset's 'auto' background and near were set for a capture in a room."""
    capture, config = trainer.capture, trainer.config
    if capture is None or not capture.room:
        return
    chosen = [f"background {config.background}"] if settings.background in (None, "auto") else []
    if settings.near is None:
        chosen.append(f"near {config.near_fraction:g}")
    if chosen:
        report(
            f"fit-nerf: {100 * capture.outside:.0f} % of the sparse points lie outside the scene box, "
            f"a capture in a room: {', '.join(chosen)} (--background, --near to choose)"
        )


def _message(metrics) -> str:
    """The success line: held-out PSNR (and in the region) beside the voxel size, and the time."""
    voxel = f"voxel {1000 * metrics['voxel_size']:.1f} mm"
    region = metrics.get("region")
    if region is not None:
        size = " x ".join(f"{high - low:.2f}" for low, high in zip(*region))
        voxel = (
            f"region PSNR {metrics['held_out_region_psnr']:.2f} dB, {voxel} in the {size} m region "
            f"({1000 * metrics['background_voxel_size']:.1f} mm outside)"
        )
    return (
        f"held-out PSNR {metrics['held_out_psnr']:.2f} dB over {len(metrics['held_out'])} views, {voxel}, "
        f"{metrics['train_seconds']:.0f} s of training"
    )
