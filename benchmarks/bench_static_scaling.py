"""Does a learned-simulator step cost the same on a 1k-face and a 100k-face environment?

A duck (pybullet_data, decimated to 255 faces, 0.66 m long) is dropped onto bumpy tessellated
ground of ~1k, ~10k and ~100k faces. The ground's cells are the same 0.1 m everywhere, as small
as the duck's triangles, and grow in number, not in size: near the duck every ground is the
same mesh, so the graphs, and the rollouts, must be the same.

Measured, for each ground, with the bundled FIGNet* model (one torch thread):
- step_ms: `LearnedSimulator.step`, graph_ms: `build_scene_graph`, broad_phase_ms: the face
  pairs alone, as the cached path computes them (`collision_face_pairs_from_poses`) and, for
  comparison, the functional path that gets every world triangle (`face_pairs_within_radius`);
  median over the steps of a rollout, the grounds taking turns within each step (so load from
  other jobs falls on all alike);
- peak_traced_mib: peak memory allocated through Python's allocators (tracemalloc: numpy
  arrays, not torch tensors) during one warm step, and cache_mib: what the first step leaves
  held (the static index);
- the rollouts on the three grounds, and on the 100k ground cropped to the faces within 1.5 m
  of the duck, compared bit for bit.

    .venv/bin/python benchmarks/bench_static_scaling.py --out benchmarks/results/static_scaling.json
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import time
import tracemalloc
from pathlib import Path

import numpy as np
import torch

from fignetctl.core.atomic import write_json
from fignetctl.core.broadphase import face_pairs_within_radius
from fignetctl.core.model.checkpoint import bundled_model_path, load_checkpoint
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import Scene, decimated_mesh
from fignetctl.core.model.scene_graph import SceneGraph, build_scene_graph, scene_geometry
from fignetctl.core.model.simulator import rigid_poses_from_vertices

DEFAULT_OUT = Path(__file__).parent / "results" / "static_scaling.json"
CELLS_PER_SIDE = {"1k": 22, "10k": 70, "100k": 224}  # 2 n² faces
CELL_SIZE = 0.1
DUCK_SCALE = 0.4
DUCK_UPRIGHT = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0.0, 0.0])  # its y axis up
CROP_RADIUS = 1.5


def bumpy_ground(cells_per_side, cell_size=CELL_SIZE):
    """(V, 3), (F, 3): a square grid centred on the origin, 2 triangles per cell, with bumps
    of ±2 cm that depend on (x, y) only, so every size has the same triangles near the origin."""
    ticks = (np.arange(cells_per_side + 1) - cells_per_side // 2) * cell_size
    x, y = np.meshgrid(ticks, ticks, indexing="ij")
    z = 0.02 * np.sin(3.0 * x) * np.cos(2.0 * y)
    vertices = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    index = np.arange((cells_per_side + 1) ** 2).reshape(cells_per_side + 1, cells_per_side + 1)
    a, b, c, d = index[:-1, :-1], index[1:, :-1], index[1:, 1:], index[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return vertices, faces


def cropped(vertices, faces, radius):
    """The faces with a vertex within `radius` (in x, y) of the origin, in their order, and
    their vertices, in theirs (so every index keeps its relative order)."""
    near = np.linalg.norm(vertices[:, :2], axis=1) <= radius
    faces = faces[near[faces].any(axis=1)]
    used = np.unique(faces)
    return vertices[used], np.searchsorted(used, faces)


def duck_mesh():
    import pybullet_data
    import trimesh

    duck = trimesh.load(os.path.join(pybullet_data.getDataPath(), "duck.obj"), force="mesh")
    return decimated_mesh(duck.vertices, duck.faces, 256)


def drop_scene(name, ground, duck, frames=2):
    """A Scene: the ground (static, object 0) and the duck at rest, its lowest point 4 cm above
    the ground's mean height (the bumps are ±2 cm)."""
    geometry = scene_geometry(
        [ground, duck], [1.0, DUCK_SCALE], [True, False], [[0.0, 0.5, 0.5], [1.0, 0.5, 0.5]]
    )
    positions = np.zeros((frames, 2, 3))
    quaternions = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 2, 1))
    quaternions[:, 1] = DUCK_UPRIGHT
    return Scene(name, geometry, positions, quaternions)


def seconds(function):
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


@torch.no_grad()
def step_reading_dynamic_vertex_positions(simulator, geometry, positions, quaternions):
    """LearnedSimulator.step with one line changed: it reads the dynamic vertices' positions
    from SceneGraph.dynamic_vertex_positions instead of SceneGraph.vertices (O(V))."""
    scene_graph = build_scene_graph(geometry, positions, quaternions, simulator.config.graph)
    normalized = simulator(scene_graph.graph)[: scene_graph.num_dynamic_vertex_nodes]
    previous, now = scene_graph.dynamic_vertex_positions[:2]
    next_vertices, _ = simulator.postprocess(normalized, previous, now)
    return rigid_poses_from_vertices(geometry, next_vertices, positions[2], quaternions[2])


def phase_functions(simulator, scene, positions, quaternions, with_functional_path=True):
    """name -> a function running that phase once on the frame history (3, O, ·)."""
    from fignetctl.core.model import scene_graph as graphs

    geometry, config = scene.geometry, simulator.config.graph
    functions = {"step_ms": lambda: simulator.step(geometry, positions, quaternions)}
    if hasattr(SceneGraph, "dynamic_vertex_positions"):  # absent before the change
        functions["step_proposed_ms"] = lambda: step_reading_dynamic_vertex_positions(
            simulator, geometry, positions, quaternions
        )
    functions["graph_ms"] = lambda: build_scene_graph(geometry, positions, quaternions, config)
    if hasattr(graphs, "collision_face_pairs_from_poses"):
        dynamic_now = geometry.world_vertices(positions[1], quaternions[1], geometry.dynamic_vertices)
        functions["broad_phase_ms"] = lambda: graphs.collision_face_pairs_from_poses(
            geometry, dynamic_now, positions[1], quaternions[1], config.collision_radius
        )
    if with_functional_path:
        functions["broad_phase_all_triangles_ms"] = lambda: face_pairs_within_radius(
            geometry.world_vertices(positions[1], quaternions[1])[geometry.faces],
            geometry.face_object,
            config.collision_radius,
            geometry.static,
        )
    return functions


def timed_rollouts(simulator, scenes, steps, repeats, with_functional_path=True):
    """Roll every scene out in lockstep; at each step time each phase `repeats` times on each
    scene, the scenes taking turns. Returns {scene: {phase: [(step, ms)]}}, the rollouts, and
    the face-face edge count of each step (first scene; all scenes have the same graphs)."""
    timings = {scene.name: {} for scene in scenes}
    histories = {scene.name: ([*scene.positions[:2]], [*scene.quaternions[:2]]) for scene in scenes}
    edges = []
    for step in range(steps):
        graph = build_scene_graph(
            scenes[0].geometry, *history_of(*histories[scenes[0].name]), simulator.config.graph
        )
        edges.append(int(graph.graph.edge_sets["face_face"].num_edges))
        for repeat in range(repeats):
            turn = (step * repeats + repeat) % len(scenes)
            for scene in scenes[turn:] + scenes[:turn]:
                history = history_of(*histories[scene.name])
                for phase, function in phase_functions(
                    simulator, scene, *history, with_functional_path
                ).items():
                    timings[scene.name].setdefault(phase, []).append((step, 1e3 * seconds(function)))
        for scene in scenes:
            positions, quaternions = histories[scene.name]
            new_position, new_quaternion = simulator.step(scene.geometry, *history_of(positions, quaternions))
            positions.append(new_position)
            quaternions.append(new_quaternion)
    rollouts = {name: (np.stack(p), np.stack(q)) for name, (p, q) in histories.items()}
    return timings, rollouts, edges


def history_of(positions, quaternions):
    """(3, O, 3), (3, O, 4): frames t−1, t and t again (static objects do not move)."""
    return np.stack([positions[-2], positions[-1], positions[-1]]), np.stack(
        [quaternions[-2], quaternions[-1], quaternions[-1]]
    )


def traced_memory(simulator, scene):
    """MiB traced by tracemalloc: held after a first (cold) step, peak of a second (warm) one."""
    positions = np.stack([scene.positions[0], scene.positions[1], scene.positions[1]])
    quaternions = np.stack([scene.quaternions[0], scene.quaternions[1], scene.quaternions[1]])
    fresh = drop_scene(scene.name, *ground_and_duck_of(scene))
    gc.collect()
    tracemalloc.start()
    before = tracemalloc.get_traced_memory()[0]
    simulator.step(fresh.geometry, positions, quaternions)
    held = tracemalloc.get_traced_memory()[0] - before
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    simulator.step(fresh.geometry, positions, quaternions)
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    return {"cache_mib": held / 2**20, "peak_traced_mib": peak / 2**20}


GROUNDS = {}


def ground_and_duck_of(scene):
    return GROUNDS[scene.name]


def compare_rollouts(rollouts, reference):
    """name -> bit-for-bit equality with the reference rollout and the largest difference."""
    result = {}
    for name, (positions, quaternions) in rollouts.items():
        ref_positions, ref_quaternions = rollouts[reference]
        result[name] = {
            "bit_identical": bool(
                np.array_equal(positions, ref_positions) and np.array_equal(quaternions, ref_quaternions)
            ),
            "max_abs_position_difference_m": float(np.abs(positions - ref_positions).max()),
            "max_abs_quaternion_difference": float(np.abs(quaternions - ref_quaternions).max()),
        }
    return result


def same_step_results(simulator, scenes, rollouts):
    """True when the proposed step gives bit for bit the poses of LearnedSimulator.step, at
    every frame of every rollout (None before the change)."""
    if not hasattr(SceneGraph, "dynamic_vertex_positions"):
        return None
    for scene in scenes:
        positions, quaternions = rollouts[scene.name]
        for t in range(1, len(positions)):
            history = history_of(positions[: t + 1], quaternions[: t + 1])
            expected = simulator.step(scene.geometry, *history)
            found = step_reading_dynamic_vertex_positions(simulator, scene.geometry, *history)
            if not all(np.array_equal(a, b) for a, b in zip(expected, found)):
                return False
    return True


def summarise(timings, memory, scenes, edges):
    """Per ground: median ms of each phase over all steps, and over the steps with and without
    face-face edges (contact), with the traced memory."""
    contact = np.asarray(edges) > 0
    rows = {}
    for scene in scenes:
        row = {"faces_ground": int(GROUNDS[scene.name][0][1].shape[0])}
        for phase, samples in timings[scene.name].items():
            steps, values = np.array([s for s, _ in samples]), np.array([v for _, v in samples])
            row[phase] = float(np.median(values))
            row[phase.replace("_ms", "_iqr_ms")] = [
                float(np.percentile(values, 25)),
                float(np.percentile(values, 75)),
            ]
            for label, mask in (("contact", contact[steps]), ("free", ~contact[steps])):
                row[phase.replace("_ms", f"_{label}_ms")] = (
                    float(np.median(values[mask])) if mask.any() else None
                )
        row.update(memory.get(scene.name, {}))
        rows[scene.name] = row
    return rows


PHASES = ("step_ms", "step_proposed_ms", "graph_ms", "broad_phase_ms", "broad_phase_all_triangles_ms")


def print_table(rows, ratios):
    phases = [p for p in PHASES if p in next(iter(rows.values()))]
    print(
        f"{'ground':>12} {'faces':>7} "
        + " ".join(f"{p:>14.14}" for p in phases)
        + f" {'peak MiB':>9} {'cache MiB':>9}"
    )
    for name, row in rows.items():
        cells = " ".join(f"{row[p]:14.2f}" for p in phases)
        print(
            f"{name:>12} {row['faces_ground']:7d} {cells} {row['peak_traced_mib']:9.2f} {row['cache_mib']:9.2f}"
        )
    print("columns: " + ", ".join(phases) + " (ms, medians over all steps)")
    for label in ("contact", "free"):
        cells = ", ".join(
            f"{p.replace('_ms', '')} {rows['100k'].get(p.replace('_ms', f'_{label}_ms')) or float('nan'):.2f} vs {rows['1k'].get(p.replace('_ms', f'_{label}_ms')) or float('nan'):.2f}"
            for p in phases
        )
        print(f"steps with {label:>7}: 100k vs 1k ms: {cells}")
    print("ratio 100k/1k: " + ", ".join(f"{p} {v:.2f}" for p, v in ratios.items()))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=3, help="timings of each phase per step and ground")
    parser.add_argument("--baseline", type=Path, help="a json of an earlier run to keep as 'before'")
    parser.add_argument("--label", default="after")
    parser.add_argument(
        "--no-functional-path",
        action="store_true",
        help="do not time face_pairs_within_radius on all triangles",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    simulator = load_checkpoint(bundled_model_path())
    duck = duck_mesh()
    for name, cells in CELLS_PER_SIDE.items():
        GROUNDS[name] = (bumpy_ground(cells), duck)
    GROUNDS["100k cropped"] = (cropped(*bumpy_ground(CELLS_PER_SIDE["100k"]), CROP_RADIUS), duck)
    scenes = [drop_scene(name, *GROUNDS[name]) for name in GROUNDS]
    timings, rollouts, edges = timed_rollouts(
        simulator, scenes, args.steps, args.repeats, not args.no_functional_path
    )
    memory = {scene.name: traced_memory(simulator, scene) for scene in scenes}
    rows = summarise(timings, memory, scenes, edges)
    ratios = {
        p.replace("_ms", f"{suffix}_ms"): rows["100k"][p.replace("_ms", f"{suffix}_ms")]
        / rows["1k"][p.replace("_ms", f"{suffix}_ms")]
        for p in timings["1k"]
        for suffix in ("", "_contact", "_free")
        if rows["1k"][p.replace("_ms", f"{suffix}_ms")]
    }
    rollouts["100k via rollout()"] = rollout(simulator, drop_scene("100k", *GROUNDS["100k"]), args.steps)
    proposed_equals_step = same_step_results(simulator, scenes, rollouts)
    result = {
        "machine": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "torch": torch.__version__,
            "cpu_count": os.cpu_count(),
            "torch_threads": 1,
            "load_average_1min": os.getloadavg()[0],
        },
        "model": str(bundled_model_path().name),
        "steps": args.steps,
        "repeats_per_step": args.repeats,
        "face_face_edges_per_step": edges,
        "cell_size_m": CELL_SIZE,
        "memory_method": "tracemalloc (numpy and Python objects; torch tensors are not traced)",
        args.label: {
            "per_ground": rows,
            "ratio_100k_over_1k": ratios,
            "rollouts_equal_to_1k": compare_rollouts(rollouts, "1k"),
            "step_proposed_equals_step": proposed_equals_step,
        },
    }
    if args.baseline is not None:
        previous = json.loads(args.baseline.read_text())
        result["before"] = previous.get("before", previous.get("after"))
    print_table(rows, ratios)
    print(f"step_proposed gives the same poses as LearnedSimulator.step: {proposed_equals_step}")
    print(f"face-face edges per step (1k ground): {edges}")
    for name, same in result[args.label]["rollouts_equal_to_1k"].items():
        print(
            f"rollout on {name:>20}: bit-identical to 1k: {same['bit_identical']}, max |Δposition| {same['max_abs_position_difference_m']:.3g} m"
        )
    write_json(args.out, result)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
