"""What accuracy costs in time: sweeps of the knobs that trade one for the other.

DESIGN.md, "What the user asked for beyond the paper", item 1. Each knob is swept over a few
settings; every setting is a point (seconds, error) measured for real and repeated, stored as
median and quartiles with the number of values behind them, and the points that no other point
beats on both axes form the Pareto front.

Knobs and what a point is:

- ``decimation``: the bundled FIGNet* rolls out ground truth (PyBullet on the full meshes) from
  frames 0–1 with every mesh decimated to at most n_f faces. Error: translation RMSE (m) of the
  dynamic objects at the last rollout step, one value per trajectory; seconds: one
  `LearnedSimulator.step`, one value per step; peak torch memory of the network part.
- ``architecture``: bundled FIGNet vs FIGNet*, the same rollouts; plus bench-memory's step and
  training-step memory and time (bench/memory.py).
- ``collision-radius``: the bundled FIGNet* with other face–face radii (off its trained
  0.2 m the inputs are out of distribution); face–face edges per graph too.
- ``message-passing``: small FIGNet* models trained with one budget (`train_steps`) for a few
  (latent size, message-passing steps); error: one-step translation error (mm) on held-out
  ground-truth frames; seconds: one step.
- ``marching-cubes``: extract-mesh's grid resolution; error: symmetric Chamfer distance to the
  capture's ground-truth mesh as a fraction of the object's largest side; seconds: one
  `extract_object` (object and environment meshes). The box is the ground-truth mesh's bounds,
  padded as extract-mesh pads its mask box, so segmentation does not enter the figure.
- ``nerf-steps``: held-out PSNR against training seconds, from a `fit-nerf` learning curve.
- ``device``: rollout step time on the CPU and on CUDA where torch sees a GPU.
- ``rotations``: the bundled FIGNet* averaged over K turns of the scene about gravity
  (`LearnedSimulator.network_acceleration`); K network evaluations per step, one graph.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from fignetctl import __version__
from fignetctl.bench.stats import median_iqr, pareto_front
from fignetctl.errors import FignetError

FORMAT = "fignetctl.tradeoff"
FORMAT_VERSION = 1
KNOBS = (
    "decimation",
    "architecture",
    "collision-radius",
    "message-passing",
    "marching-cubes",
    "nerf-steps",
    "device",
    "rotations",
)
DECIMATION_FACES = (16, 32, 64, 128, 256, 512, 1024, None)
COLLISION_RADII = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4)
ROTATIONS = (1, 2, 4, 8)
NETWORK_SIZES = ((32, 1), (32, 2), (32, 4), (16, 2), (64, 2))
GRID_RESOLUTIONS = (24, 32, 48, 64, 96, 128, 160)
NO_GPU = "no GPU here"


@dataclasses.dataclass(frozen=True)
class TradeoffSettings:
    """How much each sweep measures."""

    trajectories: int = 4
    """Ground-truth trajectories rolled out per setting (simulator knobs)."""
    steps: int = 30
    """Rollout steps from frames 0–1; the error is taken at the last one."""
    repeats: int = 3
    """Timed runs per setting and object (marching-cubes)."""
    train_steps: int = 150
    """Optimiser steps of each model of the message-passing sweep (batch 2)."""
    frames_per_trajectory: int = 8
    """Held-out frames per trajectory for the one-step error (message-passing)."""
    threads: int | None = 1
    """Torch CPU threads while measuring (1 keeps timings steady on a shared machine)."""
    device: str = "cpu"
    seed: int = 0
    quick: bool = False
    """Fewer settings (the first and a middle one), for tests and smoke runs."""


QUICK = TradeoffSettings(
    trajectories=1, steps=2, repeats=1, train_steps=2, frames_per_trajectory=2, quick=True
)


def mark_pareto(result: dict) -> dict:
    """Set `pareto` on every point of a result from the medians."""
    points = result["points"]
    sign = -1.0 if result["higher_is_better"] else 1.0
    front = pareto_front(
        [p["seconds"]["median"] for p in points], [sign * p["error"]["median"] for p in points]
    )
    for point, on_front in zip(points, front):
        point["pareto"] = bool(on_front)
    return result


def rollout_sweep_result(knob, setting_name, points, notes, config, data_path) -> dict:
    """make_result for a knob measured by rollouts: seconds per step against translation RMSE."""
    return make_result(
        knob,
        setting_name,
        "seconds per rollout step",
        f"translation RMSE after {config.steps} steps (m)",
        points,
        ROLLOUT_METHOD,
        notes,
        config=config,
        inputs=file_inputs(data_path),
    )


def make_result(
    knob,
    setting_name,
    x_label,
    y_label,
    points,
    method,
    notes=(),
    higher_is_better=False,
    config=None,
    inputs=None,
) -> dict:
    """The json of one knob's sweep, Pareto front marked."""
    result = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "fignetctl_version": __version__,
        "knob": knob,
        "setting_name": setting_name,
        "x_label": x_label,
        "y_label": y_label,
        "higher_is_better": higher_is_better,
        "config": dataclasses.asdict(config) if config is not None else None,
        "environment": environment(config.device if config is not None else "cpu"),
        "inputs": inputs or {},
        "method": method,
        "notes": list(notes),
        "points": points,
    }
    return mark_pareto(result)


def environment(device) -> dict:
    import os
    import platform

    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    try:
        import torch

        torch_version = torch.__version__
    except ImportError:  # pragma: no cover - torch is a dependency
        torch_version = None
    return {
        "device": device,
        "cpu_count": os.cpu_count(),
        "load_average": load,
        "python": platform.python_version(),
        "torch": torch_version,
    }


# -- writing: json, csv, png ----------------------------------------------------------------


def csv_rows(result: dict) -> list[list]:
    """Header and one row per point: setting, the two figures' median/q25/q75/n, pareto, and
    the scalar extras (a statistic's median)."""
    stats = ("median", "q25", "q75", "n")
    extras = (
        [k for k in result["points"][0] if k not in ("setting", "seconds", "error", "pareto")]
        if result["points"]
        else []
    )
    header = (
        ["setting"] + [f"seconds_{s}" for s in stats] + [f"error_{s}" for s in stats] + ["pareto"] + extras
    )
    rows = [header]
    for p in result["points"]:
        row = (
            [p["setting"]]
            + [p["seconds"][s] for s in stats]
            + [p["error"][s] for s in stats]
            + [int(p["pareto"])]
        )
        row += [_scalar(p.get(k)) for k in extras]
        rows.append(row)
    return rows


def _scalar(value):
    if isinstance(value, dict) and "median" in value:
        return value["median"]
    if isinstance(value, (dict, list)):
        return json.dumps(value)
    return value


def write_result(result: dict, json_path, csv_path, png_path) -> None:
    """Write the json, the csv and the plot, each atomically."""
    import csv

    from fignetctl.core.atomic import atomic_path, write_json

    write_json(json_path, result, default=_json_default)
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="") as f:
        csv.writer(f).writerows(csv_rows(result))
    with atomic_path(png_path) as tmp:
        plot_result(result, tmp)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not json: {type(value).__name__}")


def plot_result(result: dict, path) -> None:
    """Accuracy against seconds, IQR bars on both axes, each point labelled, the front joined."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = [p for p in result["points"] if p["seconds"]["n"] and p["error"]["n"]]
    figure, axes = plt.subplots(figsize=(6.4, 4.2))
    for p in points:
        x, y = p["seconds"], p["error"]
        axes.errorbar(
            x["median"],
            y["median"],
            xerr=[[x["median"] - x["q25"]], [x["q75"] - x["median"]]],
            yerr=[[y["median"] - y["q25"]], [y["q75"] - y["median"]]],
            fmt="o",
            color="C1" if p["pareto"] else "C7",
            capsize=3,
        )
        axes.annotate(
            str(p["setting"]),
            (x["median"], y["median"]),
            textcoords="offset points",
            xytext=(5, 5),
            fontsize=8,
        )
    front = sorted((p["seconds"]["median"], p["error"]["median"]) for p in points if p["pareto"])
    if front:
        axes.plot(*zip(*front), "-", color="C1", label="Pareto front")
        axes.legend(loc="best", fontsize=8)
    seconds = [v for p in points for v in (p["seconds"]["q25"], p["seconds"]["q75"])]
    if seconds and min(seconds) > 0 and max(seconds) / min(seconds) > 20:  # bars included
        axes.set_xscale("log")
    better = "higher is better" if result["higher_is_better"] else "lower is better"
    axes.set(xlabel=result["x_label"], ylabel=f"{result['y_label']} ({better})")
    axes.set_title(
        textwrap.fill(f"{result['knob']}: {result['setting_name']} (median, IQR bars)", 70), fontsize=10
    )
    axes.grid(alpha=0.3)
    figure.tight_layout()
    figure.savefig(path, dpi=110, format="png")
    plt.close(figure)


# -- ground truth -------------------------------------------------------------------------------


def make_ground_truth(path, num_trajectories, duration, seed, split="test", on_trajectory=None) -> Path:
    """A small movi-b file from PyBullet (full meshes), as `make-dataset` writes it."""
    from fignetctl.core import movi, shapes
    from fignetctl.core.trajectory import write_trajectories

    config = movi.movi_config("movi-b", duration=duration)
    assets = shapes.load_shapes("movi-b", split)
    results = []
    for result in movi.generate(assets, config, seed, range(num_trajectories)):
        results.append(result)
        if on_trajectory is not None:
            on_trajectory()
    attrs = {
        "source": "fignetctl tradeoff",
        "fignetctl_version": __version__,
        "preset": "movi-b",
        "seed": seed,
        "split": split,
        "config": config.to_json(),
    }
    return write_trajectories(path, movi.dataset_file(results, assets, config, num_trajectories, attrs))


def file_inputs(*paths) -> dict:
    from fignetctl.core.provenance import file_sha256

    return {str(p): file_sha256(p) for p in paths if p is not None and Path(p).is_file()}


# -- simulator measurements ------------------------------------------------------------------


def load_scenes(data_path, simulator_config, max_trajectories):
    """The first `max_trajectories` scenes of a file, meshes prepared for `simulator_config`."""
    from fignetctl.core.model.scene_data import EVALUATION_STATIC_REACH, scene_from_trajectory
    from fignetctl.core.trajectory import read_trajectories

    data = read_trajectories(data_path)
    keys = list(data.trajectories)[:max_trajectories]
    cache = {}
    return [
        scene_from_trajectory(data, key, simulator_config, cache, EVALUATION_STATIC_REACH) for key in keys
    ]


def timed_rollout(simulator, scene, steps):
    """Roll out `steps` steps -> (positions, quaternions, per-step seconds, failed step or None)."""
    from fignetctl.core.model.rollout import RolloutError, rollout

    seconds, last = [], [time.perf_counter()]

    def on_step(step):
        now = time.perf_counter()
        seconds.append(now - last[0])
        last[0] = now

    try:
        positions, quaternions = rollout(simulator, scene, steps, on_step)
        return positions, quaternions, seconds, None
    except RolloutError as error:
        return error.positions, error.quaternions, seconds, len(seconds)


def rollout_errors(simulator, scenes, steps, on_progress=None) -> dict:
    """Rollouts of `scenes`: per-trajectory translation (m) and rotation (deg) error at the last
    step, and every step's seconds; a rollout that stops early scores NaN (counted)."""
    from fignetctl.core.model.evaluation import errors_at

    translation, rotation, seconds, failed = [], [], [], 0
    for scene in scenes:
        horizon = min(steps, scene.positions.shape[0] - 2)
        positions, quaternions, step_seconds, failed_at = timed_rollout(simulator, scene, horizon)
        seconds += step_seconds
        if failed_at is None:
            t, r = errors_at(scene, positions, quaternions, horizon)
            translation.append(float(np.sqrt(np.mean(t**2))))
            rotation.append(float(np.mean(r)))
        else:
            failed += 1
            translation.append(float("nan"))
            rotation.append(float("nan"))
        if on_progress is not None:
            on_progress()
    return {"translation": translation, "rotation": rotation, "seconds": seconds, "failed": failed}


def network_peak_mib(simulator, scenes, device, seed=0) -> list[float]:
    """Peak torch memory (MiB, model included) of the network part of a step at the middle
    frame of each scene, by bench-memory's method."""
    import torch

    from fignetctl.bench import memory as benchmark

    peaks = []
    for scene in scenes:
        frame = max(1, min(scene.positions.shape[0] - 2, scene.positions.shape[0] // 2))
        workload = benchmark.make_workload(
            simulator, scene, frame, torch.Generator().manual_seed(seed), device
        )
        peaks.append(
            benchmark.peak_memory_mib(lambda: benchmark.run_network(workload, device), workload, device)[
                "peak_mib"
            ]
        )
    return peaks


def rollout_point(setting, simulator, scenes, config, on_progress=None, memory=True, **extras) -> dict:
    """One point of a simulator knob: rollout error against step seconds."""
    measured = rollout_errors(simulator, scenes, config.steps, on_progress)
    point = {
        "setting": setting,
        "seconds": median_iqr(measured["seconds"]),
        "error": median_iqr(measured["translation"]),
        "rotation_error_deg": median_iqr(measured["rotation"]),
        "failed_rollouts": measured["failed"],
        "trajectories": len(scenes),
    }
    if memory:
        point["step_memory_mib"] = median_iqr(network_peak_mib(simulator, scenes, config.device, config.seed))
    return {**point, **extras}


ROLLOUT_METHOD = (
    "error: translation RMSE (m) over the dynamic objects at the last rollout step (from frames 0–1 of "
    "PyBullet ground truth simulated with the full meshes), one value per trajectory, median and quartiles over "
    "trajectories; seconds: wall time of each LearnedSimulator.step (graph, network, integration, shape matching), "
    "median and quartiles over every step of every trajectory; step_memory_mib: bench-memory's peak torch memory of "
    "the network part of a step (model included) at each trajectory's middle frame."
)


def mean_dynamic_faces(scenes) -> float:
    """Mean faces per dynamic object of prepared scenes."""
    counts = [
        np.bincount(s.geometry.face_object, minlength=s.geometry.num_objects)[~s.geometry.static]
        for s in scenes
    ]
    return float(np.mean(np.concatenate(counts)))


def sweep_decimation(data_path, config: TradeoffSettings, on_progress=None, faces=None) -> dict:
    from fignetctl.core.model.apply import load_model

    simulator = load_model(None, config.device).eval()
    faces = faces or ((DECIMATION_FACES[2], None) if config.quick else DECIMATION_FACES)
    points = []
    with _torch_threads(config.threads):
        for n_f in faces:
            settings = dataclasses.replace(simulator.config, max_faces_per_object=n_f)
            scenes = load_scenes(data_path, settings, config.trajectories)
            label = "full" if n_f is None else n_f
            points.append(
                rollout_point(
                    label,
                    simulator,
                    scenes,
                    config,
                    on_progress,
                    mean_faces_per_dynamic_object=mean_dynamic_faces(scenes),
                )
            )
    notes = [
        "the bundled FIGNet* was trained on meshes decimated to at most 256 faces; "
        "settings other than 256 are out of its training distribution",
        "ground truth: PyBullet on the full meshes (convex decomposition, as make-dataset), so no setting matches it by construction",
    ]
    return rollout_sweep_result("decimation", "faces per object n_f", points, notes, config, data_path)


def sweep_architecture(data_path, config: TradeoffSettings, on_progress=None) -> dict:
    from fignetctl.bench import memory as benchmark
    from fignetctl.core.model.apply import load_model

    simulators = {
        "FIGNet": load_model("fignet-movi-b", config.device).eval(),
        "FIGNet*": load_model("fignet-star-movi-b", config.device).eval(),
    }
    points = []
    with _torch_threads(config.threads):
        for label, simulator in simulators.items():
            scenes = load_scenes(data_path, simulator.config, config.trajectories)
            points.append(rollout_point(label, simulator, scenes, config, on_progress))
        bench = benchmark.run_benchmark(
            [data_path],
            simulators,
            benchmark.BenchmarkSettings(
                samples=config.trajectories,
                repeats=config.repeats,
                seed=config.seed,
                device=config.device,
                threads=config.threads,
            ),
        )
    models = next(iter(bench["data"].values()))["models"]
    for point in points:
        model = models[point["setting"]]
        point["train_step_memory_mib"] = model["train_memory"]["peak_mib"]
        point["bench_step_memory_mib"] = model["step_memory"]["peak_mib"]
        point["train_step_ms"] = model["times_ms"]["train_step_ms"]
        point["edges_total"] = model["edges"]["total"]
    notes = [
        "bundled checkpoints: FIGNet is FIGNet*'s lineage with surface edges for its last 1000 steps "
        "(docs/simulator.md, 'The bundled checkpoints')",
        f"memory and train-step figures: bench-memory (benchmark.run_benchmark), {config.trajectories} (trajectory, frame) pairs × {config.repeats} repeats",
    ]
    return rollout_sweep_result("architecture", "FIGNet vs FIGNet*", points, notes, config, data_path)


def face_face_edges(simulator, scenes, every=5) -> list[int]:
    """Face–face edges of the graph of every `every`-th ground-truth frame."""
    from fignetctl.core.model.graph import FACE_FACE
    from fignetctl.core.model.scene_graph import build_scene_graph

    counts = []
    for scene in scenes:
        for t in range(1, scene.positions.shape[0] - 1, every):
            graph = build_scene_graph(
                scene.geometry,
                scene.positions[t - 1 : t + 2],
                scene.quaternions[t - 1 : t + 2],
                simulator.config.graph,
            ).graph
            counts.append(graph.edge_sets[FACE_FACE].num_edges if FACE_FACE in graph.edge_sets else 0)
    return counts


def sweep_collision_radius(data_path, config: TradeoffSettings, on_progress=None, radii=None) -> dict:
    from fignetctl.core.model.apply import load_model

    base = load_model(None, config.device).eval()
    radii = radii or (COLLISION_RADII[2:4] if config.quick else COLLISION_RADII)
    scenes = load_scenes(data_path, base.config, config.trajectories)
    points = []
    with _torch_threads(config.threads):
        for radius in radii:
            simulator = base.with_graph_config(collision_radius=radius)
            edges = median_iqr(face_face_edges(simulator, scenes))
            points.append(
                rollout_point(radius, simulator, scenes, config, on_progress, face_face_edges=edges)
            )
    notes = [
        "the bundled FIGNet* was trained at a 0.2 m radius: every other radius feeds it face–face edges it never saw "
        "(out of distribution), so its error away from 0.2 m says as much about the training as about the radius",
        "face_face_edges: hyper-edges (both directions) of the graph of every 5th ground-truth frame",
    ]
    return rollout_sweep_result("collision-radius", "collision radius (m)", points, notes, config, data_path)


def one_step_errors(simulator, scenes, frames_per_trajectory, seed) -> tuple[list, list, list]:
    """Held-out one-step translation errors (mm, RMSE over dynamic objects) of the model and of
    constant velocity, and the step seconds, at frames drawn evenly from each trajectory."""
    errors, baseline, seconds = [], [], []
    for scene in scenes:
        count = scene.positions.shape[0]
        for t in np.unique(np.linspace(1, count - 2, frames_per_trajectory).round().astype(int)):
            dynamic = ~scene.geometry.static
            started = time.perf_counter()
            position, _ = simulator.step(
                scene.geometry, scene.positions[t - 1 : t + 2], scene.quaternions[t - 1 : t + 2]
            )
            seconds.append(time.perf_counter() - started)
            truth = scene.positions[t + 1][dynamic]
            guess = 2 * scene.positions[t][dynamic] - scene.positions[t - 1][dynamic]
            errors.append(1e3 * float(np.sqrt(np.mean(np.sum((position[dynamic] - truth) ** 2, axis=1)))))
            baseline.append(1e3 * float(np.sqrt(np.mean(np.sum((guess - truth) ** 2, axis=1)))))
    return errors, baseline, seconds


def sweep_message_passing(
    train_path, test_path, config: TradeoffSettings, on_progress=None, sizes=None
) -> dict:
    from fignetctl.core.model.network import NetworkConfig
    from fignetctl.core.model.training import TrainingSettings, make_trainer, simulator_config_for

    sizes = sizes or (NETWORK_SIZES[:2] if config.quick else NETWORK_SIZES)
    training = TrainingSettings(
        steps=config.train_steps,
        batch_size=2,
        normalizer_accumulation_steps=config.train_steps,
        checkpoint_every=10**9,
        seed=config.seed,
    )
    points = []
    with _torch_threads(config.threads):
        for latent, steps in sizes:
            network = NetworkConfig(latent_size=latent, mlp_hidden_size=latent, message_passing_steps=steps)
            settings = dataclasses.replace(simulator_config_for("fignet-star", "tiny"), network=network)
            trainer = make_trainer(train_path, settings, training, config.device)
            started = time.perf_counter()
            trainer.run()
            train_seconds = time.perf_counter() - started
            simulator = trainer.simulator.eval()
            scenes = load_scenes(test_path, simulator.config, config.trajectories)
            errors, baseline, seconds = one_step_errors(
                simulator, scenes, config.frames_per_trajectory, config.seed
            )
            points.append(
                {
                    "setting": f"L{latent}×MP{steps}",
                    "seconds": median_iqr(seconds),
                    "error": median_iqr(errors),
                    "latent_size": latent,
                    "message_passing_steps": steps,
                    "parameters": sum(p.numel() for p in simulator.parameters()),
                    "train_seconds": round(train_seconds, 2),
                    "final_loss_mean_last_10": float(np.mean([h["loss"] for h in trainer.history[-10:]])),
                    "constant_velocity_error_mm": median_iqr(baseline),
                }
            )
            if on_progress is not None:
                on_progress()
    method = (
        "each model: FIGNet* with latent L (MLP hidden L, 2 hidden layers) and MP message-passing steps, trained "
        f"{config.train_steps} steps at batch 2 from seed {config.seed} on the training file; error: one-step translation RMSE (mm) "
        "of the dynamic objects from ground-truth frames t−1, t, per held-out frame, median and quartiles over frames; seconds: that step's wall time"
    )
    notes = [
        f"{config.train_steps} training steps is a budget, not convergence: the figures compare what each size learns for the same steps",
        "constant_velocity_error_mm: x_t + (x_t − x_{t−1}) on the same frames, for scale",
    ]
    return make_result(
        "message-passing",
        "latent size × message-passing steps",
        "seconds per step",
        "one-step translation error (mm)",
        points,
        method,
        notes,
        config=config,
        inputs=file_inputs(train_path, test_path),
    )


# -- mesh extraction --------------------------------------------------------------------------


def chamfer_fraction(mesh, truth, samples=20000, seed=0) -> float:
    """Symmetric mean closest-point distance between surface samples, over the truth's largest
    side (as benchmarks/bench_extract_mesh.py); NaN for an empty mesh."""
    from scipy.spatial import cKDTree

    if len(mesh.faces) == 0:
        return float("nan")
    a, b = mesh.sample(samples, seed=seed), truth.sample(samples, seed=seed)
    chamfer = 0.5 * (cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())
    return float(chamfer / truth.extents.max())


def capture_objects(capture) -> list:
    """(name, ground-truth trimesh) of each prompted object of a render-views capture."""
    import trimesh

    capture = Path(capture)
    prompts = capture / "prompts.json"
    if not prompts.is_file():
        raise FignetError(f"{capture}: no prompts.json; pass the folder `fignetctl render-views` wrote")
    names = [obj["name"] for obj in json.loads(prompts.read_text())["objects"]]
    return [
        (name, trimesh.load(capture / "ground_truth" / "objects" / f"{name}.obj", force="mesh"))
        for name in names
    ]


def sweep_marching_cubes(
    capture, nerf_path, config: TradeoffSettings, on_progress=None, resolutions=None
) -> dict:
    from fignetctl.core.mesh_extraction import ExtractionSettings, extract_object, padded_box
    from fignetctl.core.nerf.io import load_nerf

    model = load_nerf(nerf_path)
    resolutions = resolutions or (GRID_RESOLUTIONS[:2] if config.quick else GRID_RESOLUTIONS)
    objects = capture_objects(capture)
    points = []
    for resolution in resolutions:
        settings = ExtractionSettings(resolution=resolution, faces=0)
        errors, seconds, faces = [], [], []
        for name, truth in objects:
            box = padded_box(truth.bounds, settings.padding)
            for _ in range(config.repeats):
                started = time.perf_counter()
                extraction = extract_object(model.density, box, settings)
                seconds.append(time.perf_counter() - started)
            errors.append(chamfer_fraction(extraction.object_mesh, truth, seed=config.seed))
            faces.append(len(extraction.object_mesh.faces))
            if on_progress is not None:
                on_progress()
        points.append(
            {
                "setting": resolution,
                "seconds": median_iqr(seconds),
                "error": median_iqr(errors),
                "per_object_chamfer": dict(zip([n for n, _ in objects], errors)),
                "faces_made": median_iqr(faces),
            }
        )
    method = (
        "error: symmetric Chamfer distance (mean closest-point distance of 20,000 surface samples each way) of the "
        "undecimated marching-cubes object mesh to the capture's ground-truth mesh, over the object's largest side; one value per "
        f"object, median and quartiles over objects; seconds: extract_object (object + environment), {config.repeats} runs per object, "
        "median and quartiles over objects × runs; box: the ground-truth mesh's bounds padded by ExtractionSettings.padding"
    )
    notes = [
        f"density: {nerf_path} ({json.dumps({k: v for k, v in model.metrics.items() if k != 'held_out'})})"
    ]
    return make_result(
        "marching-cubes",
        "grid resolution (vertices along the box's longest side)",
        "seconds per extract_object",
        "Chamfer / object size",
        points,
        method,
        notes,
        config=config,
        inputs=file_inputs(nerf_path),
    )


def sweep_nerf_steps(curve_path, config: TradeoffSettings) -> dict:
    """Points of a fit-nerf learning curve (benchmarks/bench_nerf.py's json): held-out PSNR
    against training seconds; one run, so each point is n=1."""
    from fignetctl.core.containers import require_regular_file

    try:
        data = json.loads(require_regular_file(curve_path).read_text())
    except (ValueError, UnicodeDecodeError) as error:  # JSONDecodeError is a ValueError
        raise FignetError(f"{curve_path}: not a json learning curve ({type(error).__name__})") from None
    if not isinstance(data, dict):
        raise FignetError(f"{curve_path}: not a json learning curve (benchmarks/bench_nerf.py writes one)")
    try:
        points = _nerf_curve_points(data)
    except (KeyError, TypeError, AttributeError, ValueError) as error:
        raise FignetError(
            f"{curve_path}: not a fit-nerf learning curve ({type(error).__name__}: {error})"
        ) from None
    if not points:
        raise FignetError(f"{curve_path}: no learning curve in it (benchmarks/bench_nerf.py writes one)")
    notes = [
        f"reused from {curve_path} ({data.get('machine', 'machine not recorded')}, capture {data.get('capture')}): "
        "one training run per preset, so there is no spread (n = 1 per point)"
    ]
    method = (
        "held-out PSNR (dB) of the views fit-nerf holds out, against cumulative training seconds at that step"
    )
    return make_result(
        "nerf-steps",
        "fit-nerf steps",
        "training seconds",
        "held-out PSNR (dB)",
        points,
        method,
        notes,
        higher_is_better=True,
        config=config,
        inputs=file_inputs(curve_path),
    )


def _nerf_curve_points(data: dict) -> list:
    """The (setting, seconds, PSNR) points of benchmarks/bench_nerf.py's json."""
    points = []
    for run in data.get("results", []):
        for row in run.get("curve", []):
            single = lambda v: {"median": float(v), "q25": float(v), "q75": float(v), "n": 1}
            points.append(
                {
                    "setting": f"{run.get('preset', '?')} {row['step']}",
                    "seconds": single(row["train_seconds"]),
                    "error": single(row["held_out_psnr"]),
                    "depth_error_percent_of_scene": row.get("depth_error_percent_of_scene"),
                }
            )
    return points


def sweep_device(data_path, config: TradeoffSettings, on_progress=None) -> dict:
    import torch

    from fignetctl.core.model.apply import load_model

    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    points = []
    for device in devices:
        simulator = load_model(None, device).eval()
        scenes = load_scenes(data_path, simulator.config, config.trajectories)
        local = dataclasses.replace(config, device=device)
        with _torch_threads(config.threads if device == "cpu" else None):
            points.append(rollout_point(device, simulator, scenes, local, on_progress))
    notes = (
        []
        if "cuda" in devices
        else [f"cuda: {NO_GPU} (torch.cuda.is_available() is False); only the CPU was measured"]
    )
    result = rollout_sweep_result("device", "torch device", points, notes, config, data_path)
    result["cuda"] = torch.cuda.get_device_name(0) if "cuda" in devices else NO_GPU
    return result


def sweep_rotations(data_path, config: TradeoffSettings, on_progress=None, counts=None) -> dict:
    from fignetctl.core.model.apply import load_model

    simulator = load_model(None, config.device).eval()
    counts = counts or (ROTATIONS[:2] if config.quick else ROTATIONS)
    scenes = load_scenes(data_path, simulator.config, config.trajectories)
    points = []
    with _torch_threads(config.threads):
        for count in counts:
            simulator.rotations = count
            points.append(rollout_point(count, simulator, scenes, config, on_progress))
    notes = [
        "K turns by 2πk/K about gravity, each answer turned back and averaged: exactly equivariant to those turns",
        "the graph is built once per step and the network runs on K copies of it in one batch",
    ]
    return rollout_sweep_result("rotations", "turns about gravity averaged", points, notes, config, data_path)


def _torch_threads(threads):
    from fignetctl.bench.memory import torch_threads

    return torch_threads(threads)
