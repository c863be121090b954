"""The learned hard cases of tests/stability/test_learned_rollouts.py as figures, with the
materials the model was trained on (MOVi-B's) and with the paper's FIGNet* table.

The scenes and measures are the tests' own; this prints what each test asserts on, for both
sets of properties, and writes them to json (docs/stability.md has the table).

    python benchmarks/learned_hard_cases.py --out docs/results/learned-hard-cases.json
    python benchmarks/learned_hard_cases.py --model path/to/model.pt --out hard.json
    python benchmarks/learned_hard_cases.py --model path/to/model.pt --rotations 4 --out hard-4.json
"""

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' scenes

import tests.stability.test_learned_rollouts as cases
from fignetctl.bench.options import add_rotations_option
from fignetctl.core.atomic import write_json
from fignetctl.core.model.apply import load_model, rollout_trajectory
from fignetctl.core.model.rollout import RolloutError
from fignetctl.core.trajectory import read_trajectories, write_trajectories

PAPER = {"dynamic": (0.5, 0.5), "static": (0.5, 0.3)}  # friction, restitution (paper's FIGNet* table)


def with_properties(path, paper):
    """The scene file as the tests write it (MOVi-B's materials), or with the paper's table."""
    if paper:
        data = read_trajectories(path)
        trajectory = data.trajectories["0"]
        for kind, is_static in (("dynamic", False), ("static", True)):
            trajectory.friction[trajectory.static == is_static] = PAPER[kind][0]
            trajectory.restitution[trajectory.static == is_static] = PAPER[kind][1]
        write_trajectories(path, data)
    return path


def measure(model, folder, paper):
    def scene(name, bodies, statics=()):
        return with_properties(cases.scene_file(folder / name, bodies, statics), paper)

    def roll(path, steps, **options):
        return rollout_trajectory(
            model, read_trajectories(path), steps, free_flight=True, keep_out=True, **options
        ).trajectories["0"]

    def deepest(trajectory, meshes, every=1):
        return float(
            -min(cases.lowest_z(trajectory, meshes, f) for f in range(0, trajectory.num_frames, every))
        )

    found = {}
    box = trimesh.creation.box([1, 1, 1])
    t = roll(scene("rest.h5", [(box, [0, 0, 0.5], [0, 0, 0])]), 500, sleep=True)
    found["rest_drift_m"] = float(np.linalg.norm(t.positions[:, 1] - t.positions[1, 1], axis=1).max())
    t = roll(scene("stack.h5", [(box, [0, 0, 0.5 + k], [0, 0, 0]) for k in range(3)]), 200, sleep=True)
    found["stack_max_moved_m"] = float(np.linalg.norm(t.positions[:, 1:] - t.positions[1, 1:], axis=2).max())
    rod = trimesh.creation.box([2.0, 0.05, 0.05])
    t = roll(scene("rod.h5", [(rod, [0, 0, 0.5], [0, 0, 0])]), 120)
    found["rod_deepest_into_floor_m"] = deepest(t, {"floor": cases.FLOOR, "body0": rod})
    found["rod_rest_height_error_m"] = float(abs(t.positions[-1, 1, 2] - 0.025))
    plate, small = trimesh.creation.box([3.0, 3.0, 0.02]), trimesh.creation.box([0.5, 0.5, 0.5])
    t = roll(scene("plate.h5", [(small, [0, 0, 2.0], [0, 0, -8.0])], [(plate, [0, 0, 0.99])]), 40)
    found["plate_deepest_below_top_m"] = 1.0 - (
        -deepest(t, {"floor": cases.FLOOR, "static0": plate, "body0": small})
    )
    found["plate_end_z_m"] = float(t.positions[-1, 2, 2])
    for size in (0.02, 5.0):
        cube = trimesh.creation.box([size] * 3)
        steps = int(round(1.5 / (cases.DT / np.sqrt(2.1 / size))))
        t = roll(scene("cube.h5", [(cube, [0, 0, 1.5 * size], [0, 0, 0])]), steps, sim_scale="auto")
        found[f"cube_{size:g}m_deepest_fraction_of_size"] = (
            deepest(t, {"floor": cases.FLOOR, "body0": cube}) / size
        )
        found[f"cube_{size:g}m_rest_height_error_fraction_of_size"] = float(
            abs(t.positions[-1, 1, 2] - size / 2) / size
        )
    bodies = [
        (box, [-2, 0, 2], [3, 0, 0]),
        (trimesh.creation.icosphere(2, 0.6), [2, 0, 1.5], [-3, 0.5, 0]),
        (trimesh.creation.cylinder(0.4, 1.2), [0, 2, 2.5], [0, -2, 0]),
    ]
    try:
        t = roll(scene("long.h5", bodies), 1000, sleep=True)
    except RolloutError as error:  # a model that diverges: the case fails, the others stand
        return {**found, "long_finite": False, "long_stopped": str(error)}
    found["long_finite"] = bool(np.isfinite(t.positions).all() and np.isfinite(t.quaternions).all())
    found["long_deepest_into_floor_m"] = deepest(
        t, {"floor": cases.FLOOR, **{f"body{k}": m for k, (m, _, _) in enumerate(bodies)}}, 10
    )
    found["long_max_abs_position_m"] = float(np.abs(t.positions[:, 1:]).max())
    return found


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", default=None, help="model file (default: the bundled FIGNet*)")
    add_rotations_option(parser)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    logging.basicConfig(
        level=logging.ERROR
    )  # the paper's table is outside the model's: rollout warns on every scene
    model = load_model(args.model, rotations=args.rotations)
    result = {"model": args.model or "bundled fignet-star-movi-b", "rotations": model.rotations}
    with tempfile.TemporaryDirectory() as folder:
        for name, paper in (("movi_b_materials", False), ("paper_fignet_star_table", True)):
            result[name] = measure(model, Path(folder), paper)
    for key in result["movi_b_materials"]:
        print(
            f"{key:48s} {result['movi_b_materials'][key]!s:>22} "
            f"{result['paper_fignet_star_table'].get(key, '-')!s:>22}"
        )
    write_json(args.out, result)


if __name__ == "__main__":
    main()
