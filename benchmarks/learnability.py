"""Learnability: overfit a few movi-b trajectories and measure what the model still cannot
explain (the fraction of one-step target variance unexplained, FVU, on the very frames it was
trained on, without noise) and how far its rollout drifts from them.

A model whose FVU stays high on two trajectories after thousands of visits per frame has a
problem no amount of data fixes (its input, target, loss or size). The bar
(fignetctl.core.model.learnability.bar): FVU <= 10 %, and a rollout that tracks the training
trajectories: at 10 and 50 steps within 0.1 m of PyBullet restarted every frame from the same
state on them (measured here too). `--check` exits 1 when the bar is not met.

    python benchmarks/learnability.py data/movi-b-train.h5 --trajectories 2 --steps 3000 \
        -o benchmarks/results/learnability.json

`--model FILE` measures a model trained elsewhere instead, e.g. by `fignetctl train` on a file
holding just those trajectories, which checkpoints and resumes a run too long for one sitting:

    fignetctl make-dataset --preset movi-b -n 2 --seed 1 -o data/movi-b-train-2.h5
    fignetctl train data/movi-b-train-2.h5 -o overfit.pt --noise 0 0 --steps 20000 --batch-size 4
    python benchmarks/learnability.py data/movi-b-train-2.h5 --model overfit.pt
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np
import torch

from fignetctl.core.atomic import write_json
from fignetctl.core.ceilings import evaluate_ceilings
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.evaluation import errors_at
from fignetctl.core.model.learnability import (
    bar,
    fraction_unexplained,
    one_step_examples,
    overfit,
    rigid_fraction_unexplained,
)
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.training import simulator_config_for
from fignetctl.core.trajectory import read_trajectories

HORIZONS = (1, 10, 50)
TRACKED = (10, 50)
"""The horizons at which the rollout must track its training trajectories."""


def rollout_errors(simulator, scenes, horizons=HORIZONS) -> dict:
    """Translation RMSE (m) and mean rotation error (deg) of the rollouts of the training scenes."""
    out = {}
    for steps in horizons:
        translation, rotation = [], []
        for scene in scenes:
            if scene.positions.shape[0] > 1 + steps:
                positions, quaternions = rollout(simulator, scene, steps)
                t, r = errors_at(scene, positions, quaternions, steps)
                translation.append(t)
                rotation.append(r)
        if translation:
            out[f"{steps}_steps"] = {
                "translation_rmse_m": float(np.sqrt(np.mean(np.concatenate(translation) ** 2))),
                "rotation_error_deg": float(np.mean(np.concatenate(rotation))),
            }
    return out


def measure_model(path, data):
    """A model file's fit of the trajectories of `data`: (simulator, its scenes, FVU, rigid FVU)."""
    simulator = load_model(path)  # in eval mode
    scenes = scenes_from_data(data, simulator.config, TRAINING_STATIC_REACH)
    fvu = fraction_unexplained(simulator, one_step_examples(simulator, scenes))
    return simulator, scenes, fvu, rigid_fraction_unexplained(simulator, scenes)


def train_and_measure(args, data, curve, started):
    """Overfit a model on `data` as the options say, appending the FVU at each --report-at
    step to `curve`; returns (simulator, its scenes, FVU, rigid FVU, mean loss of the last 100 steps)."""
    config = simulator_config_for(
        "fignet-star",
        args.size,
        0.2,
        256,
        state=args.state,
        static_receivers=False,
        contact_velocity=args.contact_velocity,
    )
    scenes = scenes_from_data(data, config, TRAINING_STATIC_REACH)
    report_at = sorted({int(step) for step in args.report_at.split(",") if step} - {args.steps})
    trainer = overfit(
        config,
        scenes,
        args.steps,
        args.batch_size,
        tuple(args.learning_rate),
        args.loss,
        args.precision,
        args.seed,
        until_step=report_at[0] if report_at else None,
        noise=tuple(args.noise),
        frame_sampling=args.frame_sampling,
        gravity=data.gravity,
    )
    examples = one_step_examples(trainer.simulator, scenes)
    for step in report_at + [args.steps]:
        trainer.run(until_step=step)
        fvu = fraction_unexplained(trainer.simulator.eval(), examples)
        rigid = rigid_fraction_unexplained(trainer.simulator, scenes)
        trainer.simulator.train()
        curve.append(
            {
                "step": step,
                "seconds": time.perf_counter() - started,
                "fraction_unexplained": fvu["all"],
                "rigid_fraction_unexplained": rigid["all"],
            }
        )
        print(json.dumps(curve[-1]), flush=True)
    simulator = trainer.simulator.eval()
    return simulator, scenes, fvu, rigid, float(np.mean([h["loss"] for h in trainer.history[-100:]]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("--trajectories", type=int, default=2)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--size", default="small")
    parser.add_argument("--state", default="velocities", choices=["velocities", "positions"])
    parser.add_argument("--loss", default="mse", choices=["mse", "huber"])
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"])
    parser.add_argument("--learning-rate", type=float, nargs=2, default=(1e-3, 1e-4))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--frame-sampling", default="uniform", choices=["uniform", "motion"], help="train's --frame-sampling"
    )
    parser.add_argument(
        "--contact-velocity", action="store_true", help="train's --contact-velocity (face-face edges)"
    )
    parser.add_argument(
        "--noise",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("M", "RAD"),
        help="training's per-object jitter of frame t (train's: 0.003 0.003); FVU is measured without",
    )
    parser.add_argument(
        "--report-at", default="", help="comma-separated steps at which FVU is also measured (one schedule)"
    )
    parser.add_argument("-o", "--output", default=None)
    parser.add_argument("--check", action="store_true", help="exit 1 when the learnability bar is not met")
    parser.add_argument(
        "--model",
        default=None,
        help="measure this model file instead of training one (the training options are then ignored)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    data = read_trajectories(args.data)
    data = dataclasses.replace(data, trajectories=dict(list(data.trajectories.items())[: args.trajectories]))
    started = time.perf_counter()
    curve = []
    if args.model:
        simulator, scenes, fvu, rigid = measure_model(args.model, data)
        final_loss = None
    else:
        simulator, scenes, fvu, rigid, final_loss = train_and_measure(args, data, curve, started)
    seconds = time.perf_counter() - started
    rollouts = rollout_errors(simulator, scenes)
    ceiling_state = "velocity" if simulator.config.uses_velocities else "finite-difference"
    ceiling = evaluate_ceilings(data, HORIZONS, num_trajectories=args.trajectories, states=(ceiling_state,))[
        "states"
    ][ceiling_state]
    verdict = bar(
        fvu["all"],
        {int(key.split("_")[0]): row["translation_rmse_m"] for key, row in rollouts.items()},
        {row["steps"]: row["translation_rmse_m"] for row in ceiling if row["steps"] in TRACKED},
    )
    result = {
        "args": vars(args),
        "model": args.model,
        "train_seconds": None if args.model else seconds,
        "fraction_unexplained": fvu,
        "rigid_fraction_unexplained": rigid,
        "curve": curve,
        "rollout": rollouts,
        "ceiling": {"state": ceiling_state, "horizons": ceiling},
        "bar": verdict,
        "final_loss": final_loss,
    }
    print(
        json.dumps(
            {
                k: result[k]
                for k in (
                    "fraction_unexplained",
                    "rigid_fraction_unexplained",
                    "rollout",
                    "bar",
                    "final_loss",
                    "train_seconds",
                )
            },
            indent=1,
        )
    )
    if args.output:
        write_json(args.output, result)
    tracks = ", ".join(
        f"{row['steps']} steps {row['model_m']:.3f} m (at most {row['at_most_m']:.3f})"
        for row in verdict["tracks"]
    )
    print(
        f"learnability bar {'met' if verdict['met'] else 'NOT met'}: FVU {verdict['fvu']['value']:.3f} "
        f"(at most {verdict['fvu']['at_most']:.2f}); rollout of its training trajectories {tracks}"
    )
    if args.check and not verdict["met"]:
        sys.exit(1)


if __name__ == "__main__":
    main()
