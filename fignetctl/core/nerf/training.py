"""Fitting a NerfModel to posed images, with exact resume.

Each step draws `rays_per_batch` pixels from every training view (one torch Generator, whose
state is saved), jitters each ray's first sample, renders, and minimises the colour MSE (plus
optional terms: total variation of the density grid, the rays' distortion) with Adam. The
density grid grows at `upsample_steps` (the optimiser restarts then, as in DVGO) and the
occupancy grid is refreshed every `occupancy_every` steps after `occupancy_warmup`; both are
functions of the step, so a run resumed from a checkpoint repeats what an uninterrupted run does.
"""

from __future__ import annotations

import dataclasses
import json
import time

import numpy as np
import torch

from fignetctl.core.nerf.config import NerfConfig, for_capture
from fignetctl.core.nerf.data import load_views, training_rays
from fignetctl.core.nerf.evaluation import evaluate_views, psnr
from fignetctl.core.nerf.io import load_nerf, save_nerf
from fignetctl.core.nerf.model import NerfModel
from fignetctl.core.nerf.rays import camera_reach, scene_bounds
from fignetctl.core.nerf.region import RegionRequest, check_seen, ray_hits, resolve_region
from fignetctl.errors import FignetError


def rays_through_region(model: NerfModel, origins, directions):
    """Indices (N,) of the rays (R, 3 origins and directions) that cross the model's region in
    front of their origin, or None without a region."""
    if model.region is None:
        return None
    hits = ray_hits(origins.cpu().numpy(), directions.cpu().numpy(), model.region)
    return torch.as_tensor(np.flatnonzero(hits))


def make_optimizer(model: NerfModel, config: NerfConfig):
    groups = [
        {
            "params": [*model.field.density_grids(), *model.field.feature_grids()],
            "lr": config.learning_rate_grid,
            "base_lr": config.learning_rate_grid,
        },
    ]
    if model.field.colour_mlp is not None:
        groups.append(
            {
                "params": list(model.field.colour_mlp.parameters()),
                "lr": config.learning_rate_mlp,
                "base_lr": config.learning_rate_mlp,
            }
        )
    if model.background_logit.requires_grad:
        groups.append(
            {
                "params": [model.background_logit],
                "lr": config.learning_rate_grid,
                "base_lr": config.learning_rate_grid,
            }
        )
    return torch.optim.Adam(groups, betas=(0.9, 0.99))


class NerfTrainer:
    """Holds model, optimiser, rays and random state; `run` trains to `config.steps`."""

    def __init__(self, model: NerfModel, views, config: NerfConfig, device="cpu", data_hash=""):
        self.model, self.views, self.config, self.device = model.to(device), views, config, device
        self.train_views, self.held_out_views = views.split(config.holdout_every)
        self.origins, self.directions, self.colours = training_rays(views, self.train_views, device)
        self.through_region = (
            rays_through_region(model, self.origins, self.directions) if config.region_rays > 0 else None
        )
        self.optimizer = make_optimizer(model, config)
        self.generator = torch.Generator().manual_seed(config.seed)
        self.step, self.seconds, self.history, self.data_hash = 0, 0.0, [], data_hash
        self.provenance = None  # the stamp saved files carry (provenance.stamp); None: the version alone
        self.capture = None  # a new fit's config.CaptureKind, which its 'auto' settings followed

    def learning_rate_factor(self) -> float:
        return self.config.learning_rate_decay ** (
            min(self.step, self.config.steps) / max(self.config.steps, 1)
        )

    def _before_step(self) -> None:
        config = self.config
        if self.step in config.upsample_steps:
            self.model.field.upsample_density(config.grid_resolution_at(self.step))
            self.model.field.upsample_features(config.feature_resolution_at(self.step))
            self.model.refresh_occupancy()
            self.optimizer = make_optimizer(self.model, config)
        elif self.step >= config.occupancy_warmup and self.step % config.occupancy_every == 0:
            self.model.refresh_occupancy()
        for group in self.optimizer.param_groups:
            group["lr"] = group["base_lr"] * self.learning_rate_factor()

    def _ray_batch(self) -> torch.Tensor:
        """`rays_per_batch` ray indices: `region_rays` of them among the rays through the region."""
        count = self.config.rays_per_batch
        through = self.through_region
        focused = round(count * self.config.region_rays) if through is not None and len(through) else 0
        index = torch.randint(len(self.origins), (count - focused,), generator=self.generator)
        if focused:
            picked = torch.randint(len(through), (focused,), generator=self.generator)
            index = torch.cat([index, through[picked]])
        return index.to(self.device)

    def train_step(self) -> dict:
        started = time.perf_counter()
        self._before_step()
        index = self._ray_batch()
        jitter = torch.rand(self.config.rays_per_batch, generator=self.generator).to(self.device)
        warm = self.step >= self.config.occupancy_warmup
        out = self.model.render_rays(
            self.origins[index],
            self.directions[index],
            jitter=jitter,
            weight_threshold=None if warm else 0.0,
            transmittance_threshold=self.config.transmittance_threshold if warm else 0.0,
            with_distortion=self.config.distortion_weight > 0,
        )
        mse = torch.mean((out["rgb"] - self.colours[index]) ** 2)
        loss = mse
        if self.config.tv_weight > 0:
            loss = loss + self.config.tv_weight * self.model.field.total_variation()
        if self.config.distortion_weight > 0:
            loss = loss + self.config.distortion_weight * out["distortion"].mean()
        if not torch.isfinite(loss):
            raise FignetError(
                f"the loss became {float(loss.detach())} at step {self.step + 1}; try a lower learning rate or check the images"
            )
        self.optimizer.zero_grad(set_to_none=True)
        if loss.requires_grad:  # else no ray met occupied space and nothing learnable coloured it
            loss.backward()
            self.optimizer.step()
        self.step += 1
        self.seconds += time.perf_counter() - started
        record = {
            "step": self.step,
            "loss": float(loss.detach()),
            "psnr": psnr(float(mse.detach())),
            "seconds": round(self.seconds, 4),
        }
        self.history.append(record)
        return record

    def run(self, checkpoint_path=None, on_step=None, until_step=None) -> None:
        """Train to config.steps (or `until_step`), checkpointing every config.checkpoint_every steps."""
        last = self.config.steps if until_step is None else min(until_step, self.config.steps)
        self.model.train()
        while self.step < last:
            record = self.train_step()
            if on_step is not None:
                on_step(record)
            if checkpoint_path and (self.step % self.config.checkpoint_every == 0 or self.step == last):
                self.save(checkpoint_path)
        self.model.eval()

    def evaluate(self, depth_truth=None):
        """Held-out PSNR (on every pixel, and with a region on the pixels whose rays pass
        through it; depth error with ground truth), and the renderings."""
        return evaluate_views(
            self.model, self.views, self.held_out_views, depth_truth, region=self.model.region
        )

    def state(self) -> dict:
        return {
            "step": self.step,
            "seconds": self.seconds,
            "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(),
            "history": json.dumps(self.history),
            "data_hash": self.data_hash,
        }

    def load_state(self, state: dict) -> None:
        self.step, self.seconds = int(state["step"]), float(state["seconds"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])
        self.history = json.loads(state["history"])

    def inputs(self) -> dict:
        cameras = self.views.cameras
        return {
            "data_hash": self.data_hash,
            "trained_width": int(cameras.width),
            "trained_height": int(cameras.height),
            "image_scale": float(self.views.scale),
            "train_views": [int(i) for i in self.train_views],
            "held_out_views": [int(i) for i in self.held_out_views],
        }

    def save(self, path, metrics=None) -> None:
        save_nerf(path, self.model, metrics, self.inputs(), self.state(), self.provenance)


def make_trainer(
    image_dir, cameras, config: NerfConfig, device="cpu", resume_from=None, data_hash="", region=None
) -> NerfTrainer:
    """A trainer on the images of `cameras` in `image_dir`, resumed from a nerf.pt if given (with
    the region it was fitted in). `region`: a region.RegionRequest (or a (2, 3) box) to fit
    finely; None or 'scene': one grid over the scene box."""
    if resume_from is not None:
        model, state = load_nerf(resume_from, device=device, with_training_state=True)
        if state is None:
            raise FignetError(f"{resume_from}: holds no training state to resume from")
        if data_hash and state.get("data_hash") and state["data_hash"] != data_hash:
            raise FignetError(f"{resume_from}: was trained on other images or cameras; start a new run")
        config = dataclasses.replace(model.config, steps=config.steps)
        model.config = config
        views = load_views(image_dir, cameras, config.max_image_side)
        trainer = NerfTrainer(model, views, config, device, data_hash)
        trainer.load_state(state)
        return trainer
    views = load_views(image_dir, cameras, config.max_image_side)
    bounds = scene_bounds(cameras.points, cameras.c2w, config.bounds_margin)
    config, capture = for_capture(config, cameras.points, bounds)
    if config.near_fraction > 0:
        config = dataclasses.replace(config, near=config.near_fraction * camera_reach(cameras.c2w))
    if isinstance(region, RegionRequest):
        region = resolve_region(region, cameras, bounds)
    if region is not None:
        check_seen(region, views.cameras, views.split(config.holdout_every)[0])
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = NerfModel(config, bounds, region=region)
    trainer = NerfTrainer(model, views, config, device, data_hash)
    trainer.capture = capture
    return trainer


def finish(trainer: NerfTrainer, path, depth_truth=None):
    """Evaluate on the held-out views and write the final nerf.pt with its metrics."""
    trainer.model.refresh_occupancy()
    result, renderings = trainer.evaluate(depth_truth)
    last = trainer.history[-1] if trainer.history else {}
    model = trainer.model
    metrics = {
        "held_out_psnr": result["psnr"],
        "held_out_region_psnr": result.get("region_psnr"),
        "held_out": result["per_view"],
        "steps": trainer.step,
        "train_seconds": trainer.seconds,
        "train_batch_psnr": last.get("psnr"),
        "occupied_fraction": model.occupancy.fraction,
        "region": None if model.region is None else model.region.tolist(),
        "voxel_size": model.voxel_size,
        "background_voxel_size": model.field.voxel_size,
        "region_occupied_fraction": model.occupancy.region_fraction,
    }
    trainer.save(path, metrics)
    return metrics, renderings
