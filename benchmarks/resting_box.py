"""Does a model hold a box still on the floor, and what in the scene changes its answer?

The suite's learned hard case (tests/stability/test_learned_rollouts.py) sets a cube on the
floor at rest and asks that it stay within 1 cm. This rolls out that scene, built as
`build-graph` builds one (MOVi-B's rubber on MOVi-B's floor, frame time 1/30 s), with the cube
2 m across by default (`--size`; the suite's is 1 m, the model knows 1.4-2.8 m), over a grid
of what could make it unlike the training data:

- the gap between the box and the floor: 0, as the suite and `build-graph` place it, or the
  0.8-1.0 mm above the floor at which PyBullet's recordings leave resting objects;
- its tessellation: the 12 triangles of a box, or subdivided 1-3 times (768 triangles, as the
  MOVi-B cube before the model's decimation);
- its mass.

For each, the box's rise over the first step and its largest displacement over the rollout,
of the network alone (no free flight, keep-out or sleeping) and with `--guards` as `rollout`
runs it. A model that holds a resting box still answers 0 everywhere.

    python benchmarks/resting_box.py --model MODEL --out resting-box.json
"""

import argparse
import itertools
import json

import numpy as np
import trimesh

from fignetctl.bench.options import add_rotations_option
from fignetctl.core.atomic import write_json
from fignetctl.core.model.apply import load_model, rollout_trajectory
from fignetctl.core.scene_building import ACTIVE, Properties, build_scene, drop_history

FLOOR_SIZE = (40.0, 40.0, 1.0)


def resting_box_scene(size=2.0, gap=0.0, subdivisions=0, mass=ACTIVE.mass):
    """A scene file: a cube of side `size` at rest with its bottom `gap` above the floor (top at z = 0)."""
    box = trimesh.creation.box([size] * 3)
    for _ in range(subdivisions):
        box = box.subdivide()
    floor = trimesh.creation.box(FLOOR_SIZE)
    start = np.array([0.0, 0.0, size / 2 + gap])
    return build_scene(
        (box.vertices, box.faces),
        (floor.vertices, floor.faces),
        origin=start,
        positions=drop_history(start, start=start, velocity=np.zeros(3)),
        active=Properties(mass=mass, friction=ACTIVE.friction, restitution=ACTIVE.restitution),
        environment_origin=(0.0, 0.0, -FLOOR_SIZE[2] / 2),
    )


def measure(simulator, scene, steps, guards):
    """(rise over the first step, largest displacement over `steps` steps), metres."""
    result = rollout_trajectory(
        simulator, scene, steps, sleep=guards, free_flight=guards, keep_out=guards
    ).trajectories["scene"]
    moved = result.positions[1:, 1] - result.positions[1, 1]
    return float(moved[1, 2]), float(np.linalg.norm(moved, axis=1).max())


def main():
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--model", default=None, help="a model file (default: the bundled FIGNet*)")
    parser.add_argument("--size", type=float, default=2.0, help="the cube's side, metres")
    parser.add_argument("--gaps", type=float, nargs="+", default=[0.0, 0.001], metavar="METRES")
    parser.add_argument("--subdivisions", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--masses", type=float, nargs="+", default=[1.0, 5.0, 20.0], metavar="KG")
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--guards", action="store_true", help="free flight, keep-out and sleeping")
    add_rotations_option(parser)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    simulator = load_model(args.model, rotations=args.rotations)
    rows = []
    for gap, subdivisions, mass in itertools.product(args.gaps, args.subdivisions, args.masses):
        scene = resting_box_scene(args.size, gap, subdivisions, mass)
        rise, largest = measure(simulator, scene, args.steps, args.guards)
        row = {
            "gap_mm": gap * 1000,
            "faces": len(scene.meshes["object"].faces),
            "mass_kg": mass,
            "first_step_rise_mm": round(rise * 1000, 3),
            "largest_displacement_mm": round(largest * 1000, 2),
        }
        print(json.dumps(row), flush=True)
        rows.append(row)
    write_json(
        args.out,
        {
            "model": args.model or "bundled FIGNet*",
            "size_m": args.size,
            "steps": args.steps,
            "guards": args.guards,
            "rotations": simulator.rotations,
            "rows": rows,
        },
    )


if __name__ == "__main__":
    main()
