"""fit-nerf: posed images (a folder and cameras.npz) -> a radiance field, nerf.pt."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fignetctl.core.rerun_log import DEFAULT_VIEWER
from fignetctl.errors import SettingError
from fignetctl.stages import DEVICES, check, no_progress, resolve_device, setting, to_stderr, write_summary


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
    resume: bool = setting(False, "Continue the run saved in --output where it stopped.")
    seed: int = setting(0, "Random seed, 0 to 2**32 - 1.", low=0, high=2**32 - 1)
    device: str = setting("auto", "Torch device; 'auto' uses CUDA when available.", choices=DEVICES)
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
    none listens), and the --json summary. Returns the summary (output and the metrics stored in
    nerf.pt) with a one-line `message` (held-out PSNR)."""
    import torch

    from fignetctl.core.cameras import read_cameras
    from fignetctl.core.nerf.config import preset_config
    from fignetctl.core.nerf.data import inputs_hash
    from fignetctl.core.nerf.training import finish, make_trainer
    from fignetctl.core.nerf.visualize import log_fit_step, log_held_out
    from fignetctl.core.provenance import stamp
    from fignetctl.core.rerun_log import live_recording, viewer_address

    check(settings)
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
        seed=settings.seed,
    )
    data_hash = inputs_hash(images_dir, cameras)
    resume_from = path if settings.resume and path.exists() else None
    trainer = make_trainer(images_dir, camera_set, config, device, resume_from, data_hash)
    trainer.provenance = stamp(images=images_dir, cameras=cameras)
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
    message = (
        f"held-out PSNR {metrics['held_out_psnr']:.2f} dB over {len(metrics['held_out'])} views, "
        f"{metrics['train_seconds']:.0f} s of training"
    )
    if rerun_path:
        from fignetctl.core.nerf.visualize import log_fit_to_rerun

        log_fit_to_rerun(rerun_path, trainer, renderings)
    summary = {"output": str(path), **metrics}
    write_summary(json_path, summary, trainer.provenance)
    return {**summary, "message": message}
