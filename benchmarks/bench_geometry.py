"""Benchmark of the geometry core: closest points, broad phase, shape matching.

Prints the figures and writes them as json (--out). Every timing is the median of
--repeats runs, except the O(F²) brute-force broad phase, which runs --brute-force-repeats
times (default once: it takes minutes) and also checks that the broad phase returns
exactly its pairs.

    .venv/bin/python benchmarks/bench_geometry.py --out benchmarks/results/geometry.json
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

from fignetctl.core.atomic import write_json
from fignetctl.core.broadphase import brute_force_face_pairs, face_pairs_within_radius
from fignetctl.core.shape_matching import (
    _fit_rigid_transform_torch_native,
    fit_rigid_transform,
    fit_rigid_transform_torch,
)
from fignetctl.core.transforms import random_quaternions, transform_points
from fignetctl.core.triangles import closest_points_triangles

DEFAULT_OUT = Path(__file__).parent / "results" / "geometry.json"


def median_seconds(function, repeats):
    """Median wall-clock seconds of `repeats` calls (after one warm-up call)."""
    function()
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        durations.append(time.perf_counter() - start)
    return statistics.median(durations)


def random_triangle_pairs(rng, count):
    """(count, 3, 3) x2: unit-cube triangles, the second set shifted by N(0, 0.5) per pair."""
    triangles_a = rng.random((count, 3, 3))
    triangles_b = rng.random((count, 3, 3)) + rng.normal(0, 0.5, (count, 1, 3))
    return triangles_a, triangles_b


def bench_closest_points(rng, pair_count, repeats):
    triangles_a, triangles_b = random_triangle_pairs(rng, pair_count)
    seconds = median_seconds(lambda: closest_points_triangles(triangles_a, triangles_b), repeats)
    return {"pairs": pair_count, "seconds": seconds, "pairs_per_second": pair_count / seconds}


def scene_objects():
    """Trimesh objects of a cluttered scene, about 10k faces in all."""
    return [
        trimesh.creation.icosphere(subdivisions=3, radius=0.35),
        trimesh.creation.icosphere(subdivisions=3, radius=0.25),
        trimesh.creation.icosphere(subdivisions=3, radius=0.3),
        trimesh.creation.capsule(height=0.5, radius=0.2, count=[32, 32]),
        trimesh.creation.cylinder(radius=0.3, height=0.4, sections=64),
        trimesh.creation.torus(major_radius=0.3, minor_radius=0.1, major_sections=48, minor_sections=24),
        trimesh.creation.box(extents=[0.5, 0.4, 0.3]),
        trimesh.creation.icosphere(subdivisions=3, radius=0.2),
        trimesh.creation.box(extents=[0.6, 0.6, 0.1]),
    ]


def cluttered_scene(rng):
    """Objects at random poses on a 3 x 3 grid of 0.7 m cells over a static 2-triangle floor.

    returns : triangles (F, 3, 3), face_object (F,), object_static (O,)
    """
    parts = []
    for index, mesh in enumerate(scene_objects()):
        centre = np.array([0.7 * (index % 3 - 1), 0.7 * (index // 3 - 1), 0.36]) + rng.uniform(-0.05, 0.05, 3)
        vertices = transform_points(mesh.vertices, 1.0, centre, random_quaternions(rng, 1)[0])
        parts.append(vertices[mesh.faces])
    floor = np.array([[-20.0, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]])[[[0, 1, 2], [0, 2, 3]]]
    parts.append(floor)
    face_object = np.concatenate([np.full(len(part), index) for index, part in enumerate(parts)])
    object_static = np.zeros(len(parts), dtype=bool)
    object_static[-1] = True
    return np.concatenate(parts), face_object, object_static


def bench_broad_phase(rng, radius, repeats, brute_force_repeats):
    scene = cluttered_scene(rng)
    found = face_pairs_within_radius(*scene[:2], radius, scene[2])
    seconds = median_seconds(lambda: face_pairs_within_radius(*scene[:2], radius, scene[2]), repeats)
    result = {
        "faces": len(scene[0]),
        "objects": len(scene[2]),
        "radius": radius,
        "pairs": int(found[0].size),
        "broad_phase_seconds": seconds,
    }
    if brute_force_repeats > 0:
        result.update(bench_brute_force(scene, radius, brute_force_repeats, found, seconds))
    return result


def bench_brute_force(scene, radius, repeats, found, broad_phase_seconds):
    """Times the O(F²) reference and checks that the broad phase found exactly its pairs."""
    durations = []
    for _ in range(repeats):
        start = time.perf_counter()
        expected = brute_force_face_pairs(*scene[:2], radius, scene[2])
        durations.append(time.perf_counter() - start)
    same = np.array_equal(found[0], expected[0]) and np.array_equal(found[1], expected[1])
    return {
        "brute_force_seconds": statistics.median(durations),
        "speedup": statistics.median(durations) / broad_phase_seconds,
        "same_pairs_as_brute_force": bool(same),
    }


def bench_shape_matching(rng, object_count, point_count, repeats):
    source = rng.normal(0, 0.3, (object_count, point_count, 3))
    positions, quaternions = rng.normal(size=(object_count, 3)), random_quaternions(rng, object_count)
    target = transform_points(source, 1.0, positions, quaternions) + rng.normal(0, 1e-3, source.shape)
    tensors = torch.tensor(source), torch.tensor(target)
    seconds = {
        "numpy": median_seconds(lambda: fit_rigid_transform(source, target), repeats),
        # CPU tensors are handed to the numpy implementation ...
        "torch_cpu": median_seconds(lambda: fit_rigid_transform_torch(*tensors), repeats),
        # ... because torch's own ops (the GPU path) are slower on the CPU.
        "torch_ops_cpu": median_seconds(
            lambda: _fit_rigid_transform_torch_native(torch, *tensors, None), repeats
        ),
    }
    result = {"objects": object_count, "points_per_object": point_count}
    for name, value in seconds.items():
        result[f"{name}_seconds"] = value
        result[f"{name}_transforms_per_second"] = object_count / value
    return result


def machine_description():
    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": torch.__version__,
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }


def print_report(results):
    closest, broad, shape = results["closest_points"], results["broad_phase"], results["shape_matching"]
    print(
        f"closest points : {closest['pairs_per_second']:,.0f} pairs/s"
        f" ({closest['pairs']} pairs in {closest['seconds']:.3f} s)"
    )
    print(
        f"broad phase    : {broad['faces']} faces, radius {broad['radius']} m,"
        f" {broad['pairs']} pairs in {broad['broad_phase_seconds']:.3f} s"
    )
    if "brute_force_seconds" in broad:
        print(
            f"brute force    : {broad['brute_force_seconds']:.1f} s, speed-up x{broad['speedup']:,.0f},"
            f" same pairs: {broad['same_pairs_as_brute_force']}"
        )
    print(
        f"shape matching : numpy {shape['numpy_transforms_per_second']:,.0f} /s,"
        f" torch CPU tensors {shape['torch_cpu_transforms_per_second']:,.0f} /s,"
        f" torch ops on the CPU {shape['torch_ops_cpu_transforms_per_second']:,.0f} /s"
        f" ({shape['objects']} objects x {shape['points_per_object']} points)"
    )


def parse_arguments():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="json file to write")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--brute-force-repeats", type=int, default=1, help="0 skips the brute-force reference"
    )
    parser.add_argument("--pairs", type=int, default=100_000)
    parser.add_argument("--radius", type=float, default=0.03)
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main():
    arguments = parse_arguments()
    rng = np.random.default_rng(arguments.seed)
    results = {
        "machine": machine_description(),
        "repeats": arguments.repeats,
        "closest_points": bench_closest_points(rng, arguments.pairs, arguments.repeats),
        "broad_phase": bench_broad_phase(
            rng, arguments.radius, arguments.repeats, arguments.brute_force_repeats
        ),
        "shape_matching": bench_shape_matching(rng, 1000, 300, arguments.repeats),
    }
    print_report(results)
    write_json(arguments.out, results, indent=2)
    print(f"wrote {arguments.out}")


if __name__ == "__main__":
    main()
