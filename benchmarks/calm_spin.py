"""Does the spin a velocity-state model makes up in calm frames hold its rotations back?

`regime_errors.py` finds the network's step changing an object's spin where nothing turns it
(free fall, at rest) by several times what the recording does. This rolls a model out on
held-out trajectories three ways and compares the rotation error after 10 and 50 steps: the
network alone; with every object whose step the network itself leaves calm (its velocity
changes by free fall's within `training.CALM_TOLERANCE`, or it ends at rest) keeping its spin
(orientation advanced at its angular velocity, angular velocity unchanged; translation the
network's), `own`; and the same wherever the recording's step from that frame is calm
(`training.object_regimes`: free fall or at rest), `oracle`, which reads the recording as no
model could. Constant velocity is beside them, and each against the network alone as `evaluate`
compares (`evaluation.compare`: the rotation error's difference, with a 95 % bootstrap interval
over trajectories).

    python benchmarks/calm_spin.py benchmarks/results/velocity-continued-gpu-400-steps/model.pt \
        data/movi-b-test.h5 -o calm-spin.json
"""

from __future__ import annotations

import argparse

import numpy as np

from fignetctl.core.atomic import write_json
from fignetctl.core.model.checkpoint import load_checkpoint
from fignetctl.core.model.evaluation import compare, constant_velocity_baseline, errors_at, summarize_errors
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import EVALUATION_STATIC_REACH, scene_from_trajectory
from fignetctl.core.model.training import CALM_TOLERANCE, REGIMES, object_regimes
from fignetctl.core.trajectory import read_trajectories
from fignetctl.core.transforms import quat_from_rotation_vector, quat_multiply

HORIZONS = (10, 50)
METHODS = ("alone", "own", "oracle")


class CalmSpin:
    """A velocity-state simulator whose calm objects keep their spin, for one rollout of `scene`
    from its frames 0 and 1 (`oracle`: calm as the recording's step from the same frame)."""

    def __init__(self, simulator, scene, oracle=False):
        self.simulator, self.scene, self.oracle = simulator, scene, oracle
        self.gravity = np.asarray(simulator.config.gravity, np.float64)
        self.steps = 0
        self.kept = 0
        self.dynamic_steps = 0

    @property
    def config(self):
        return self.simulator.config

    def calm(self, geometry, velocities, next_velocities):
        """(O,) bool: the dynamic objects whose step is calm."""
        if self.oracle:
            frame = 1 + self.steps
            calm = np.zeros(geometry.num_objects, bool)
            if frame + 1 < self.scene.positions.shape[0]:
                calm = object_regimes(self.scene, frame, self.gravity, True) < REGIMES.index("impact")
        else:
            dt = self.config.dt
            tolerance = CALM_TOLERANCE * np.linalg.norm(self.gravity) * dt  # m/s over a step
            falling = np.linalg.norm(next_velocities - velocities - self.gravity * dt, axis=1) < tolerance
            calm = falling | (np.linalg.norm(next_velocities, axis=1) < tolerance)
        return calm & ~geometry.static

    def predict(self, geometry, positions, quaternions, free_flight=None, velocities=None):
        position, quaternion, velocity, angular = self.simulator.predict(
            geometry, positions, quaternions, free_flight=free_flight, velocities=velocities
        )
        calm = self.calm(geometry, velocities[0], velocity)
        self.steps += 1
        self.kept += int(calm.sum())
        self.dynamic_steps += int((~geometry.static).sum())
        quaternion, angular = np.array(quaternion), np.array(angular)
        angular[calm] = velocities[1][calm]
        turn = quat_from_rotation_vector(velocities[1][calm] * self.config.dt)
        quaternion[calm] = quat_multiply(turn, quaternions[1][calm])
        return position, quaternion, velocity, angular


def rollouts(simulator, scene, methods, steps):
    """method -> (positions, quaternions), and method -> share of dynamic object-steps kept."""
    runs = {"constant_velocity": constant_velocity_baseline(scene, steps, simulator.config.gravity, scene.dt)}
    kept = {}
    for method in methods:
        if method == "alone":
            runs[method] = rollout(simulator, scene, steps)
            continue
        proxy = CalmSpin(simulator, scene, oracle=method == "oracle")
        runs[method] = rollout(proxy, scene, steps)
        kept[method] = (proxy.kept, proxy.dynamic_steps)
    return runs, kept


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("model", help="a velocity-state model file")
    parser.add_argument("data", help="a held-out trajectory file with recorded velocities")
    parser.add_argument("-n", type=int, default=40, help="its first n trajectories")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args()
    simulator = load_checkpoint(args.model)
    if not simulator.config.uses_velocities:
        raise SystemExit(
            f"error: {args.model} is a two-frame model; this compares the spin a velocity state carries"
        )
    data = read_trajectories(args.data)
    if not np.isclose(simulator.config.dt, data.dt, rtol=1e-3):
        raise SystemExit(
            f"error: {args.data}'s frames are {data.dt:.6g} s apart, the model steps {simulator.config.dt:.6g} s"
        )
    names = ["constant_velocity", *args.methods]
    records = {name: {horizon: [] for horizon in HORIZONS} for name in names}
    kept = {method: [0, 0] for method in args.methods if method != "alone"}
    cache = {}
    for key in list(data.trajectories)[: args.n]:
        scene = scene_from_trajectory(data, key, simulator.config, cache, EVALUATION_STATIC_REACH)
        runs, shares = rollouts(simulator, scene, args.methods, max(HORIZONS))
        for method, (count, total) in shares.items():
            kept[method][0] += count
            kept[method][1] += total
        for name, (positions, quaternions) in runs.items():
            for horizon in HORIZONS:
                translation, rotation = errors_at(scene, positions, quaternions, horizon)
                records[name][horizon].append({"translation": translation, "rotation": rotation})
        print(key, flush=True)
    result = {"model": args.model, "data": args.data, "trajectories": args.n, "methods": {}}
    for name in names:
        result["methods"][name] = {}
        for horizon in HORIZONS:
            figures = summarize_errors(records[name][horizon])
            if "alone" in records and name != "alone":
                figures["against_alone"] = compare(records[name][horizon], records["alone"][horizon])
            result["methods"][name][f"{horizon}_steps"] = figures
        if name in kept:
            result["methods"][name]["kept_share"] = kept[name][0] / max(kept[name][1], 1)
    for name, figures in result["methods"].items():
        cells = []
        for horizon in HORIZONS:
            cell = figures[f"{horizon}_steps"]
            paired = ""
            if "against_alone" in cell:
                against = cell["against_alone"]
                low, high = against["rotation_error_difference_deg_95"]
                paired = (
                    f" ({against['rotation_error_difference_deg']:+.2f}° [{low:+.2f}, {high:+.2f}] vs alone)"
                )
            cells.append(
                f"{horizon} steps {cell['translation_rmse_m']:.3f} m / {cell['rotation_error_deg']:.2f}°{paired}"
            )
        share = f", kept {figures['kept_share']:.3f} of object-steps" if "kept_share" in figures else ""
        print(f"{name:18s} " + "; ".join(cells) + share)
    write_json(args.output, result)
    print(args.output)


if __name__ == "__main__":
    main()
