"""Does a model that fits its training frames roll them out? The suite's cube cases, longer.

The suite's learnability test overfits a tiny velocity-state FIGNet* for 800 steps on a rubber
cube dropped on the floor and on two cubes tossed into each other (1 s each, PyBullet, MOVi-B's
settings, 30 fps; `learnability.CUBE_CASES`) and asserts the one-step fit. This runs the same
cases for --steps steps and then asks what the rollout does with that fit, beside what physics
does with the same error:

* the model: its one-step FVU on the training frames, and its rollout of the very trajectory it
  trained on (network alone) at each horizon, translation RMSE and mean rotation error;
* PyBullet restarted every frame from the pose and velocity (the velocity-state ceiling);
* PyBullet run freely from frame 1 with every cube first moved by a nudge (`evaluate_nudged`):
  by the model's own one-step error (its rollout after one step), and by 1 mm. Where these
  stay close and the model does not, the drift is the model's, not the scene's chaos.

    python benchmarks/cube_tracking.py --steps 4000 -o benchmarks/results/cube-tracking.json
"""

from __future__ import annotations

import argparse
import sys
import time

import torch

from fignetctl.core.atomic import write_json
from fignetctl.core.ceilings import evaluate_ceilings, evaluate_nudged, horizon_errors, horizon_row
from fignetctl.core.model.learnability import (
    CUBE_CASES,
    cube_asset,
    cube_trajectories,
    fraction_unexplained,
    one_step_examples,
    overfit,
)
from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
from fignetctl.core.model.training import simulator_config_for

HORIZONS = (1, 5, 10, 15, 20, 28)


def config_of(size: str, free_motion: bool = False):
    """The velocity-state FIGNet* of a network size (the suite's: 'tiny'), decoding the change
    from free motion when `free_motion`."""
    return simulator_config_for(
        "fignet-star", size, 0.2, state="velocities", static_receivers=False, free_motion=free_motion
    )


def model_rows(simulator, data, scene) -> list:
    """The model's rollout of the trajectory it trained on: one row per horizon."""
    trajectory = next(iter(data.trajectories.values()))
    with torch.no_grad():
        positions, quaternions = rollout(simulator, scene, HORIZONS[-1])
    return [
        horizon_row(steps, data.dt, *horizon_errors(positions, quaternions, trajectory, steps))
        for steps in HORIZONS
    ]


def measure(case: str, args) -> dict:
    """Train on one case, then the model's and physics' rows for it."""
    count, seed, region = CUBE_CASES[case]
    data = cube_trajectories(count, seed, region)
    config = config_of(args.size, args.free_motion)
    scenes = scenes_from_data(data, config, TRAINING_STATIC_REACH)
    started = time.perf_counter()
    trainer = overfit(
        config,
        scenes,
        steps=args.steps,
        batch_size=4,
        learning_rate=tuple(args.learning_rate),
        noise=(args.noise, args.noise),
        seed=args.seed,
        pushforward=args.pushforward,
        calm_weight=args.calm_weight,
    )
    seconds = time.perf_counter() - started
    simulator = trainer.simulator.eval()
    fit = fraction_unexplained(simulator, one_step_examples(simulator, scenes))
    model = model_rows(simulator, data, scenes[0])
    one_step_error = model[0]["translation_rmse_m"]
    nudges = (one_step_error, 1e-3)
    nudged = evaluate_nudged(data, HORIZONS, nudges=nudges, assets=[cube_asset()])["nudges"]
    ceiling = evaluate_ceilings(data, HORIZONS, states=("velocity",), assets=[cube_asset()])
    return {
        "cubes": count,
        "training_seconds": round(seconds, 1),
        "fvu": fit["all"],
        "fvu_position": fit["position"],
        "fvu_velocity": fit["velocity"],
        "model": model,
        "physics_restarted_from_pose_and_velocity": ceiling["states"]["velocity"],
        "physics_nudged_by_the_models_one_step_error": {
            "nudge_m": one_step_error,
            "rows": nudged[f"{one_step_error:g} m"],
        },
        "physics_nudged_by_1_mm": nudged[f"{1e-3:g} m"],
    }


def print_case(case: str, result: dict) -> None:
    nudge = result["physics_nudged_by_the_models_one_step_error"]
    columns = [
        ("model", result["model"]),
        ("PyBullet restarted", result["physics_restarted_from_pose_and_velocity"]),
        (f"PyBullet nudged {1e3 * nudge['nudge_m']:.2f} mm", nudge["rows"]),
        ("PyBullet nudged 1 mm", result["physics_nudged_by_1_mm"]),
    ]
    print(
        f"\n{case} ({result['cubes']} cube(s)): FVU {result['fvu']:.4f} after {result['training_seconds']} s\n"
        "| steps | " + " | ".join(name for name, _ in columns) + " |\n"
        "|---:|" + "---:|" * len(columns)
    )
    for k, steps in enumerate(HORIZONS):
        cells = [f"{1e3 * rows[k]['translation_rmse_m']:.1f} mm" for _, rows in columns]
        print(f"| {steps} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n".join(__doc__.splitlines()[1:]),
    )
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--learning-rate", type=float, nargs=2, default=[3e-3, 3e-4])
    parser.add_argument("--noise", type=float, default=0.0, help="training jitter (m and rad); the suite's 0")
    parser.add_argument(
        "--pushforward", type=int, default=0, help="examples of each 4 from the model's own step"
    )
    parser.add_argument(
        "--calm-weight", type=float, default=0.0, help="extra loss weight of free-fall and resting vertices"
    )
    parser.add_argument(
        "--size", choices=list(PRESETS), default="tiny", help="network size (the suite's: tiny)"
    )
    parser.add_argument(
        "--free-motion", action="store_true", help="the network predicts the change from free motion"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cases", nargs="+", choices=list(CUBE_CASES), default=list(CUBE_CASES))
    parser.add_argument("-o", "--output", default=None, help="write the figures as json here")
    args = parser.parse_args()
    if args.steps < 1:
        sys.exit(f"--steps: at least 1, got {args.steps}")
    torch.set_num_threads(1)
    results = {}
    for case in args.cases:
        results[case] = measure(case, args)
        print_case(case, results[case])
    if args.output:
        write_json(
            args.output,
            {
                "command": " ".join(["python", *sys.argv]),
                "steps": args.steps,
                "learning_rate": args.learning_rate,
                "size": args.size,
                "noise": args.noise,
                "pushforward": args.pushforward,
                "calm_weight": args.calm_weight,
                "free_motion": args.free_motion,
                "horizons": list(HORIZONS),
                "cases": results,
            },
        )
        print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
