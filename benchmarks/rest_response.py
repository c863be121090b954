"""How a model answers a resting object that is given a small velocity: does it stop it?

From the last frame of held-out trajectories, every object at rest there (it moved less than
0.1 mm in the last frame) is given a velocity v of 3 mm per frame along ±x, ±y, ±z (moving
objects are lifted 50 m out of the way) and the model takes one step. Each model is given v as
it reads a state: frame t−1 moved back by v for a two-frame model, the instantaneous velocity
v (no spin) for a velocity-state one. Two responses, each projected on v and divided by |v|²:

- moved, (x_{t+1} − x_t)·v/|v|²: the share of v the object travels in the next frame;
- kept, u_{t+1}·v/|v|² (velocity-state models and PyBullet): the share of v it still has at
  the end of that frame, which the next step starts from.

For a two-frame model k = moved − 1 = a·v/|v|² says what a rollout does: −1, the object stops
(a = −v); −2, it is sent back as fast as it came, a period-2 oscillation that never settles;
0, it keeps the velocity and drifts away. For a velocity-state model kept says it: 0 stops the
object, 1 lets it drift. `--physics` adds PyBullet's own answer from the same state of the same
scene (a fresh world as make-dataset built it, one frame; make-dataset files only), which is
what physics does with what a velocity-state model is given. Beside them, the speed of each
resting object after one step from exact rest (v = 0), mm per frame, and with
`--drift-steps N` how far each resting object has moved after N steps of a rollout from the
last two recorded frames (all objects as recorded there; `--guards`: with free flight, keep-out
and sleeping, as `rollout` runs; else the network alone). `--bf16` adds how far the step from
exact rest under bfloat16 autocast, the arithmetic of `train --precision bf16`, lands from the
float32 step (mm): whether training's rounding is as large as the error at rest.

    python benchmarks/rest_response.py --model fignetctl/assets/models/fignet-star-movi-b.pt \
        --data data/movi-b-test.h5 -n 6 --physics --drift-steps 60 \
        --out docs/results/rest-response-fignet-star.json
"""

import argparse
import dataclasses
import functools
import json

import numpy as np

from fignetctl.bench.options import add_rotations_option
from fignetctl.core.atomic import write_json
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.rollout import guards_for, rollout
from fignetctl.core.model.scene_data import EVALUATION_STATIC_REACH, scene_from_trajectory
from fignetctl.core.trajectory import read_trajectories

SPEED = 0.003  # metres per frame
AT_REST = 1e-4
LIFT = np.array([0.0, 0.0, 50.0])
DIRECTIONS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)


def resting_state(positions, quaternions, static):
    """The last frame's poses with the moving objects lifted out of the way, and which objects
    rest. positions (T, O, 3), quaternions (T, O, 4) -> (O, 3), (O, 4), resting (O,) bool."""
    positions, quaternions = np.asarray(positions, np.float64), np.asarray(quaternions, np.float64)
    resting = ~static & (np.linalg.norm(positions[-1] - positions[-2], axis=1) < AT_REST)
    now = positions[-1].copy()
    now[~static & ~resting] += LIFT
    return now, quaternions[-1], resting


def pushed_velocities(positions, resting, velocity, dt):
    """(O, 3) linear velocities in m/s: `velocity` (metres per frame) on the resting objects, 0 elsewhere."""
    linear = np.zeros_like(positions)
    linear[resting] = velocity / dt
    return linear


def model_step(simulator, geometry, positions, quaternions, resting, velocity, dt):
    """One step of `simulator` with every resting object given `velocity` (metres per frame).

    returns the resting objects' displacement over the step (R, 3) and, for a velocity-state
    model, their velocity after it in metres per frame (R, 3; else None)"""
    previous = positions.copy()
    previous[resting] -= velocity
    given = None
    if simulator.config.uses_velocities:
        given = (pushed_velocities(positions, resting, velocity, dt), np.zeros_like(positions))
    following, _, linear_after, _ = simulator.predict(
        geometry, np.stack([previous, positions, positions]), np.stack([quaternions] * 3), velocities=given
    )
    moved = (following - positions)[resting]
    return moved, None if linear_after is None else linear_after[resting] * dt


def physics_step(physics, trajectory_id, positions, quaternions, resting, velocity, dt):
    """`model_step`'s answer from PyBullet (ceilings.RestartedPyBullet.frame), no object spinning."""
    following, _, linear_after, _ = physics.frame(
        trajectory_id,
        positions,
        quaternions,
        pushed_velocities(positions, resting, velocity, dt),
        np.zeros_like(positions),
    )
    return (following - positions)[resting], linear_after[resting] * dt


def responses(step, speed=SPEED):
    """moved, kept (None if the stepper gives no velocity) and the speed from rest (mm per
    frame), over the six directions, from `step(velocity (3,))` -> (moved (R, 3), kept (R, 3))."""
    moved, kept = [], []
    for direction in DIRECTIONS:
        velocity = speed * direction
        displacement, after = step(velocity)
        moved.append(displacement @ velocity / speed**2)
        kept.append(None if after is None else after @ velocity / speed**2)
    from_rest = np.linalg.norm(step(np.zeros(3))[0], axis=1) * 1000
    kept = None if kept[0] is None else np.concatenate(kept)
    return np.concatenate(moved), kept, from_rest


def bf16_difference(step):
    """(R,) mm per frame between the step from exact rest in float32 and the same step under
    bfloat16 autocast, the arithmetic `train --precision bf16` trains in (CPU)."""
    import torch

    with torch.no_grad():
        exact = step(np.zeros(3))[0]
        with torch.autocast("cpu", dtype=torch.bfloat16):
            rounded = step(np.zeros(3))[0]
    return np.linalg.norm(rounded - exact, axis=1) * 1000


def resting_drift(simulator, scene, steps, guards):
    """(R, 3) metres each object resting in the scene's last frame has moved after `steps` steps
    of a rollout that starts from its last two frames (their recorded velocities too)."""
    _, _, resting = resting_state(scene.positions, scene.quaternions, scene.geometry.static)
    last = {
        name: getattr(scene, name)[-2:]
        for name in ("positions", "quaternions", "velocities", "angular_velocities")
        if getattr(scene, name) is not None
    }
    positions, _ = rollout(simulator, dataclasses.replace(scene, **last), steps, guards=guards)
    return positions[-1, resting] - positions[1, resting]


def drift_summary(displacements, gravity, steps, guards) -> dict:
    """Percentiles of how far (R, 3) `displacements` took the resting objects, and how much of
    it was along gravity (down: positive) and across it."""
    down = np.asarray(gravity, np.float64) / np.linalg.norm(gravity)
    along = displacements @ down
    across = np.linalg.norm(displacements - along[:, None] * down, axis=1)
    distances = np.linalg.norm(displacements, axis=1)
    return {
        "steps": steps,
        "guards": guards,
        "objects": int(distances.size),
        "metres_p10_p50_p90_max": np.percentile(distances, [10, 50, 90, 100]).round(4).tolist(),
        "objects_within_1cm": int((distances < 0.01).sum()),
        "down_metres_p10_p50_p90": np.percentile(along, [10, 50, 90]).round(4).tolist(),
        "across_metres_p10_p50_p90": np.percentile(across, [10, 50, 90]).round(4).tolist(),
    }


def summarise(moved, kept, from_rest) -> dict:
    def percentiles(values):
        return np.percentile(values, [10, 50, 90]).round(3).tolist()

    summary = {
        "responses": int(moved.size),
        "moved_p10_p50_p90": percentiles(moved),
        "k_p10_p50_p90": percentiles(moved - 1.0),
        "from_rest_mm_per_frame_p50_p90_max": np.percentile(from_rest, [50, 90, 100]).round(3).tolist(),
    }
    if kept is not None:
        summary["kept_p10_p50_p90"] = percentiles(kept)
    return summary


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("-n", type=int, default=6)
    parser.add_argument("--physics", action="store_true", help="also PyBullet's answer from the same states")
    parser.add_argument(
        "--drift-steps", type=int, default=0, help="also roll out this many steps from the last frames"
    )
    parser.add_argument(
        "--guards", action="store_true", help="the drift with free flight, keep-out and sleeping"
    )
    parser.add_argument(
        "--bf16",
        action="store_true",
        help="also how far the step from rest under bfloat16 autocast lands from the float32 one",
    )
    add_rotations_option(parser)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    simulator = load_model(args.model, rotations=args.rotations)
    data = read_trajectories(args.data)
    physics = None
    if args.physics:
        from fignetctl.core.ceilings import RestartedPyBullet

        physics = RestartedPyBullet(data)
    found = {"model": [], "physics": []}
    guards = guards_for(data.dt, data.gravity, args.guards, args.guards, args.guards)
    drifts, rounding = [], []
    try:
        for key in list(data.trajectories)[: args.n]:
            scene = scene_from_trajectory(data, key, simulator.config, {}, EVALUATION_STATIC_REACH)
            state = resting_state(scene.positions, scene.quaternions, scene.geometry.static)
            if not state[2].any():
                continue
            step = functools.partial(model_step, simulator, scene.geometry, *state, dt=data.dt)
            found["model"].append(responses(step))
            if args.bf16:
                rounding.append(bf16_difference(step))
            if args.drift_steps:
                drifts.append(resting_drift(simulator, scene, args.drift_steps, guards))
            if physics is not None:
                found["physics"].append(
                    responses(functools.partial(physics_step, physics, key, *state, dt=data.dt))
                )
    finally:
        if physics is not None:
            physics.close()
    if not found["model"]:
        raise SystemExit(
            f"no object rests in the last frame of the first {args.n} trajectories; try a larger -n"
        )
    result = {
        "model": args.model,
        "rotations": simulator.rotations,
        "data": args.data,
        "speed_m_per_frame": SPEED,
    }
    for who, rows in found.items():
        if rows:
            kept = None if rows[0][1] is None else np.concatenate([row[1] for row in rows])
            result["summary" if who == "model" else who] = summarise(
                np.concatenate([row[0] for row in rows]), kept, np.concatenate([row[2] for row in rows])
            )
    if rounding:
        result["bf16_from_rest_difference_mm_p50_p90_max"] = (
            np.percentile(np.concatenate(rounding), [50, 90, 100]).round(3).tolist()
        )
    if drifts:
        result["drift"] = drift_summary(np.concatenate(drifts), data.gravity, args.drift_steps, args.guards)
    shown = ("summary", "physics", "drift", "bf16_from_rest_difference_mm_p50_p90_max")
    print(json.dumps({key: value for key, value in result.items() if key in shown}))
    write_json(args.out, result)


if __name__ == "__main__":
    main()
