"""The cost of one step of FIGNet and FIGNet* on real scenes: the paper's Table 1.

For every data file, `samples` (trajectory, frame t) pairs are drawn with a seeded generator
from the middle half of the trajectories, preferring frames where some face pair of different
objects is within the collision radius (objects touching the floor or each other). Every model
is measured on the same pairs:

- edges: the size of each edge set of the graph of step t (face–face hyper-edges counted once
  per direction, as built), mean ± std (ddof 1) over the pairs;
- runtime: `graph_ms` (build_scene_graph), `network_ms` (copy the graph to the device and run
  the network, no gradients), `step_ms` (the whole `LearnedSimulator.step`: graph, network,
  integration, shape matching) and `train_step_ms` (copy, forward, MSE loss on the dynamic
  vertices, backward, for one graph with training noise); the models take turns within every
  repeat so that a busy machine slows them alike; `warmup` untimed rounds first; median and
  quartiles over all pairs × repeats;
- peak memory: the most torch memory live on the device at any moment of the network part of
  a step (graph copy + forward) and of a training step (graph copy + forward + backward),
  above what was live before, plus the model's own parameters and buffers, which a step
  needs resident. On CUDA: `torch.cuda.max_memory_allocated` after
  `torch.cuda.reset_peak_memory_stats`. On the CPU torch keeps no such counter, so the step
  runs under `torch.profiler.profile(profile_memory=True)`, which records every allocation and
  free of torch's CPU allocator with its size and time; the running sum of those events, in
  time order, is the live memory, and its maximum the peak. (On CUDA the same profiler
  figure is kept as a cross-check.) Not counted on either device: memory that is not a torch
  tensor (numpy arrays of the graph builder, oneDNN / BLAS scratch space, the Python heap).

Untrained simulators fit their normalizers on the sampled graphs first (one accumulating
call per graph), so that they run every operation a trained model runs; weights do not
change the cost.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from fignetctl import __version__
from fignetctl.bench.stats import median_iqr
from fignetctl.core.model.graph import (
    FACE_FACE,
    MESH_TO_OBJECT,
    NODE_NODE,
    OBJECT_TO_MESH,
    EdgeSet,
    MultiGraph,
)
from fignetctl.core.model.scene_data import EVALUATION_STATIC_REACH, scenes_from_file
from fignetctl.core.model.scene_graph import build_scene_graph, collision_face_pairs
from fignetctl.core.model.training import torch_threads
from fignetctl.errors import FignetError

FORMAT = "fignetctl.bench-memory"
FORMAT_VERSION = 1
MIB = 2**20
EDGE_TYPES = (MESH_TO_OBJECT, OBJECT_TO_MESH, NODE_NODE, FACE_FACE)
TIMINGS = ("graph_ms", "network_ms", "step_ms", "train_step_ms")
FIGNET, FIGNET_STAR = "FIGNet", "FIGNet*"
# The paper's Table 1 (MOVi-B; FIGNet ran out of memory on MOVi-C).
PAPER_TABLE_1 = {
    "movi-b": {
        FIGNET: {"memory_mib": 63.38, "runtime_ms": 26.38, "edges": 24514},
        FIGNET_STAR: {"memory_mib": 50.08, "runtime_ms": 19.41, "edges": 8630},
    },
    "movi-c": {FIGNET_STAR: {"memory_mib": 71.79, "runtime_ms": 20.42, "edges": 11401}},
}
PAPER_RATIOS_MOVI_B = {
    key: PAPER_TABLE_1["movi-b"][FIGNET_STAR][key] / PAPER_TABLE_1["movi-b"][FIGNET][key]
    for key in ("edges", "memory_mib", "runtime_ms")
}
MEMORY_METHOD = {
    "cuda": "torch.cuda.max_memory_allocated() after torch.cuda.reset_peak_memory_stats(), minus "
    "the memory allocated before the step, plus the model's parameters and buffers",
    "cpu": "peak of the running sum, in time order, of the allocation/free events of torch's CPU "
    "allocator recorded by torch.profiler.profile(profile_memory=True) during the step, plus "
    "the model's parameters and buffers",
}


@dataclasses.dataclass(frozen=True)
class BenchmarkSettings:
    """How many measurements, and where."""

    samples: int = 10
    """(trajectory, frame) pairs drawn per data file (fewer if a file has fewer)."""
    repeats: int = 5
    """Timed runs of each phase per pair and model."""
    warmup: int = 1
    """Untimed runs of each phase per pair and model before the timed ones."""
    seed: int = 0
    """Draws the pairs and the training-step noise."""
    device: str = "cpu"
    """Torch device the networks run on."""
    threads: int | None = 1
    """Torch intra-op threads while measuring (None: torch's default). One thread keeps CPU
    timings steady on a shared machine: OpenMP threads that wait for a descheduled sibling
    make every operator cost milliseconds."""


@dataclasses.dataclass
class Workload:
    """One model on one (trajectory, frame) pair: the inputs of a step and of a training step."""

    simulator: torch.nn.Module
    scene: object
    frame: int
    graph: MultiGraph
    training_graph: MultiGraph
    training_rows: torch.Tensor
    training_targets: torch.Tensor

    @property
    def history(self):
        """Positions (3, O, 3) and quaternions (3, O, 4) of frames t−1, t, t+1."""
        window = slice(self.frame - 1, self.frame + 2)
        return self.scene.positions[window], self.scene.quaternions[window]


def untrained_simulators(size, collision_radius=None, max_faces=256, seed=0) -> dict:
    """{"FIGNet": ..., "FIGNet*": ...}: the same settings but for surface edges, seeded weights."""
    from fignetctl.core.model.simulator import LearnedSimulator
    from fignetctl.core.model.training import simulator_config_for

    simulators = {}
    for label, architecture in ((FIGNET, "fignet"), (FIGNET_STAR, "fignet-star")):
        with torch.random.fork_rng():
            torch.manual_seed(seed)
            config = simulator_config_for(architecture, size, collision_radius, max_faces)
            simulators[label] = LearnedSimulator(config).eval()
    return simulators


def simulators_from_files(paths) -> dict:
    """Model files -> {label: simulator}, labelled by file stem (made unique)."""
    from fignetctl.core.model.checkpoint import load_checkpoint

    return {label: load_checkpoint(path) for label, path in unique_labels(paths).items()}


def unique_labels(paths) -> dict:
    """Paths -> {label: path}, the label being the file stem, with -2, -3 ... on a repeat."""
    labels = {}
    for path in paths:
        stem, label, count = Path(path).stem, Path(path).stem, 1
        while label in labels:
            count += 1
            label = f"{stem}-{count}"
        labels[label] = Path(path)
    return labels


def architecture_of(simulator) -> str:
    return FIGNET if simulator.config.graph.surface_edges else FIGNET_STAR


def middle_frames(num_frames: int) -> range:
    """Frames t of the middle half of a trajectory that have t−1 and t+1 (at least frame 1)."""
    return range(max(1, num_frames // 4), min(num_frames - 2, (3 * num_frames) // 4) + 1)


def has_contact(scene, frame, collision_radius) -> bool:
    """True when some face pair of different objects (not both static) is within the radius."""
    vertices = scene.geometry.world_vertices(scene.positions[frame], scene.quaternions[frame])
    pair_i, _ = collision_face_pairs(scene.geometry, vertices, collision_radius)
    return len(pair_i) > 0


def sample_frames(scenes, count, rng, collision_radius) -> list[tuple[int, int, bool]]:
    """`count` distinct (scene index, frame, contact) pairs from the middle of the trajectories,
    drawn in a random order; pairs in contact first, others only to make up the count."""
    candidates = [(i, t) for i, scene in enumerate(scenes) for t in middle_frames(scene.positions.shape[0])]
    if not candidates:
        raise FignetError("no trajectory has 3 frames (t−1, t, t+1): nothing to measure")
    touching, apart = [], []
    for index in rng.permutation(len(candidates)):
        scene_index, frame = candidates[index]
        if has_contact(scenes[scene_index], frame, collision_radius):
            touching.append((scene_index, frame, True))
        elif len(apart) < count:
            apart.append((scene_index, frame, False))
        if len(touching) == count:
            break
    return (touching + apart)[:count]


def make_workload(simulator, scene, frame, noise_generator, device) -> Workload:
    """Build the step's graph and a noisy training example for one model and pair."""
    from fignetctl.core.model.training import TrainingSettings, training_example

    positions, quaternions = scene.positions[frame - 1 : frame + 2], scene.quaternions[frame - 1 : frame + 2]
    graph = build_scene_graph(scene.geometry, positions, quaternions, simulator.config.graph).graph
    example, targets = training_example(simulator.config, scene, frame, noise_generator, TrainingSettings())
    rows = torch.arange(example.num_dynamic_vertex_nodes, device=device)
    return Workload(simulator, scene, frame, graph, example.graph, rows, targets)


def copied_to(graph: MultiGraph, device) -> MultiGraph:
    """A copy of the graph on the device, always new memory (as a host-to-GPU copy is)."""

    def copy(tensor):
        return tensor.to(device, copy=True)

    edge_sets = {
        name: EdgeSet(name, copy(es.features), copy(es.senders), copy(es.receivers))
        for name, es in graph.edge_sets.items()
    }
    return MultiGraph(copy(graph.node_features), edge_sets)


def run_network(workload: Workload, device) -> torch.Tensor:
    """The network part of a step: graph to the device, normalize, encode-process-decode,
    denormalize (over the simulator's `rotations`, as a step runs it)."""
    with torch.no_grad():
        return workload.simulator.network_acceleration(copied_to(workload.graph, device))


def run_training_step(workload: Workload, device) -> float:
    """Forward and backward of one graph (no optimiser update); gradients freed after."""
    simulator = workload.simulator
    graph = copied_to(workload.training_graph, device)
    targets = simulator.normalized_targets(workload.training_targets.to(device), accumulate=False)
    predictions = simulator(graph)[workload.training_rows]
    loss = torch.mean((predictions - targets) ** 2)
    loss.backward()
    simulator.zero_grad(set_to_none=True)
    return float(loss.detach())


def phases(workload: Workload, device) -> dict:
    """TIMINGS name -> a function running that phase once."""
    simulator, geometry = workload.simulator, workload.scene.geometry
    positions, quaternions = workload.history
    return {
        "graph_ms": lambda: build_scene_graph(geometry, positions, quaternions, simulator.config.graph),
        "network_ms": lambda: run_network(workload, device),
        "step_ms": lambda: simulator.step(geometry, positions, quaternions),
        "train_step_ms": lambda: run_training_step(workload, device),
    }


def fit_normalizers(workload: Workload, device) -> None:
    """Give an untrained simulator statistics (no-op for one that has them)."""
    simulator = workload.simulator
    if simulator.node_normalizer.count.item() > 0 and simulator.acceleration_normalizer.count.item() > 0:
        return
    with torch.no_grad():
        simulator(workload.graph.to(device), accumulate=True)
        simulator(workload.training_graph.to(device), accumulate=True)
        simulator.normalized_targets(workload.training_targets.to(device), accumulate=True)


def synchronizer(device):
    """A function that waits for the device's queued work (a no-op on the CPU)."""
    device = torch.device(device)
    if device.type == "cuda":
        return lambda: torch.cuda.synchronize(device)
    return lambda: None


def timed_ms(function, synchronize) -> float:
    synchronize()
    start = time.perf_counter()
    function()
    synchronize()
    return 1e3 * (time.perf_counter() - start)


def time_phases(workloads: dict, config: BenchmarkSettings) -> dict:
    """{label: Workload} -> {label: {phase: [ms, ...]}}; models take turns within every round."""
    synchronize = synchronizer(config.device)
    functions = {label: phases(workload, config.device) for label, workload in workloads.items()}
    times = {label: {phase: [] for phase in TIMINGS} for label in workloads}
    for round_index in range(config.warmup + config.repeats):
        for label, phase_functions in functions.items():
            for phase, function in phase_functions.items():
                elapsed = timed_ms(function, synchronize)
                if round_index >= config.warmup:
                    times[label][phase].append(elapsed)
    return times


def peak_of_running_sum(times, nbytes) -> int:
    """Allocation (+) and free (−) events at `times` -> the largest sum live at any moment (≥ 0)."""
    order = np.argsort(np.asarray(times), kind="stable")
    running = np.cumsum(np.asarray(nbytes, np.int64)[order])
    return int(max(running.max(initial=0), 0))


def profiled_peak_bytes(function, device) -> int:
    """Peak of live torch memory on `device` while `function` runs, from the profiler's events."""
    from torch.profiler import ProfilerActivity, profile

    device = torch.device(device)
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    with profile(activities=activities, profile_memory=True) as profiler:
        function()
        synchronizer(device)()
    wanted = device.type.upper()
    events = [
        event
        for event in profiler.profiler.kineto_results.events()
        if event.name() == "[memory]" and event.device_type().name == wanted
    ]
    return peak_of_running_sum([e.start_ns() for e in events], [e.nbytes() for e in events])


def cuda_peak_bytes(function, device) -> int:
    """Peak of torch.cuda's allocated memory while `function` runs, above what was live before."""
    torch.cuda.synchronize(device)
    before = torch.cuda.memory_allocated(device)
    torch.cuda.reset_peak_memory_stats(device)
    function()
    torch.cuda.synchronize(device)
    return torch.cuda.max_memory_allocated(device) - before


def model_bytes(simulator) -> int:
    """Bytes of the parameters and buffers (the normalizers' statistics) of a model."""
    tensors = list(simulator.parameters()) + list(simulator.buffers())
    return sum(t.numel() * t.element_size() for t in tensors)


def peak_memory_mib(function, workload: Workload, device) -> dict:
    """The peak of one run of `function` (MiB, model included), by the device's method."""
    resident = model_bytes(workload.simulator)
    profiled = profiled_peak_bytes(function, device)
    result = {"peak_mib": (resident + profiled) / MIB, "profiler_peak_above_model_mib": profiled / MIB}
    if torch.device(device).type == "cuda":
        result["peak_mib"] = (resident + cuda_peak_bytes(function, device)) / MIB
    return result


def edge_counts(graph: MultiGraph) -> dict:
    """Edges of each type (0 for a type the graph has not) and their total; nodes."""
    counts = {name: graph.edge_sets[name].num_edges if name in graph.edge_sets else 0 for name in EDGE_TYPES}
    counts["total"] = sum(counts.values())
    counts["nodes"] = graph.num_nodes
    return counts


def measure_pair(workloads: dict, config: BenchmarkSettings) -> dict:
    """{label: Workload} of one pair -> {label: edges, memory, times}; timing first (warm)."""
    times = time_phases(workloads, config)
    results = {}
    for label, workload in workloads.items():
        step = peak_memory_mib(lambda: run_network(workload, config.device), workload, config.device)
        train = peak_memory_mib(lambda: run_training_step(workload, config.device), workload, config.device)
        results[label] = {
            "edges": edge_counts(workload.graph),
            "step_memory": step,
            "train_memory": train,
            "times_ms": times[label],
        }
    return results


def mean_std(values) -> dict:
    values = np.asarray(values, np.float64)
    std = float(values.std(ddof=1)) if len(values) > 1 else 0.0
    return {"mean": float(values.mean()), "std": std}


def summarize_model(per_pair: list[dict]) -> dict:
    """One model's per-pair results -> edges and memory mean ± std, times median and IQR."""
    edges = {name: mean_std([p["edges"][name] for p in per_pair]) for name in (*EDGE_TYPES, "total", "nodes")}
    memory = {
        kind: {key: mean_std([p[kind][key] for p in per_pair]) for key in per_pair[0][kind]}
        for kind in ("step_memory", "train_memory")
    }
    times = {phase: median_iqr([t for p in per_pair for t in p["times_ms"][phase]]) for phase in TIMINGS}
    return {"edges": edges, **memory, "times_ms": times}


def ratios(models: dict) -> dict | None:
    """FIGNet*/FIGNet of edges, memory and time, when exactly one model of each is present."""
    star = [s for s in models.values() if s["architecture"] == FIGNET_STAR]
    full = [s for s in models.values() if s["architecture"] == FIGNET]
    if len(star) != 1 or len(full) != 1:
        return None
    a, b = star[0], full[0]
    return {
        "edges": a["edges"]["total"]["mean"] / b["edges"]["total"]["mean"],
        "step_memory": a["step_memory"]["peak_mib"]["mean"] / b["step_memory"]["peak_mib"]["mean"],
        "train_memory": a["train_memory"]["peak_mib"]["mean"] / b["train_memory"]["peak_mib"]["mean"],
        "step_time": a["times_ms"]["step_ms"]["median"] / b["times_ms"]["step_ms"]["median"],
        "network_time": a["times_ms"]["network_ms"]["median"] / b["times_ms"]["network_ms"]["median"],
        "train_time": a["times_ms"]["train_step_ms"]["median"] / b["times_ms"]["train_step_ms"]["median"],
    }


def mesh_settings(config):
    """The part of a SimulatorConfig that decides how a file's meshes are prepared."""
    return config.max_faces_per_object, config.max_static_edge


def scenes_by_mesh_settings(path, simulators: dict) -> dict:
    """mesh_settings -> the file's scenes prepared that way (each setting loaded once)."""
    configs = {mesh_settings(s.config): s.config for s in simulators.values()}
    return {key: scenes_from_file(path, config, EVALUATION_STATIC_REACH) for key, config in configs.items()}


def pair_workloads(simulators: dict, scenes: dict, scene_index, frame, noise_seed, device) -> dict:
    """{label: Workload} of one pair, normalizers fitted; every model gets the same noise."""
    workloads = {}
    for label, simulator in simulators.items():
        scene = scenes[mesh_settings(simulator.config)][scene_index]
        workloads[label] = make_workload(
            simulator, scene, frame, torch.Generator().manual_seed(noise_seed), device
        )
        fit_normalizers(workloads[label], device)
    return workloads


def benchmark_file(path, simulators: dict, config: BenchmarkSettings, on_pair=None) -> dict:
    """One data file: sampled pairs, each model's summary, and the FIGNet*/FIGNet ratios."""
    scenes = scenes_by_mesh_settings(path, simulators)
    first = next(iter(simulators.values()))
    rng = np.random.default_rng(config.seed)
    pairs = sample_frames(
        scenes[mesh_settings(first.config)], config.samples, rng, first.config.graph.collision_radius
    )
    per_pair = {label: [] for label in simulators}
    for pair_index, (scene_index, frame, _) in enumerate(pairs):
        workloads = pair_workloads(
            simulators, scenes, scene_index, frame, config.seed + pair_index, config.device
        )
        for label, result in measure_pair(workloads, config).items():
            per_pair[label].append(result)
        if on_pair is not None:
            on_pair()
    return file_result(path, scenes[mesh_settings(first.config)], pairs, simulators, per_pair)


def file_result(path, scenes, pairs, simulators, per_pair) -> dict:
    """The json of one data file."""
    from fignetctl.core.provenance import file_sha256

    models = {
        label: {"architecture": architecture_of(simulators[label]), **summarize_model(results)}
        for label, results in per_pair.items()
    }
    samples = [
        {
            "trajectory": scenes[i].name,
            "frame": t,
            "contact": contact,
            **{label: per_pair[label][k] for label in per_pair},
        }
        for k, (i, t, contact) in enumerate(pairs)
    ]
    return {
        "path": str(path),
        "sha256": file_sha256(path),
        "pairs": len(pairs),
        "pairs_in_contact": sum(contact for _, _, contact in pairs),
        "models": models,
        "ratios": ratios(models),
        "samples": samples,
    }


def run_benchmark(data_paths, simulators: dict, config: BenchmarkSettings, on_pair=None) -> dict:
    """Data files and {label: simulator} -> the full result (json-ready dict)."""
    simulators = {label: s.to(config.device) for label, s in simulators.items()}
    with torch_threads(config.threads):
        files = {
            label: benchmark_file(path, simulators, config, on_pair)
            for label, path in unique_labels(data_paths).items()
        }
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "fignetctl_version": __version__,
        "environment": {
            **environment(config.device),
            "torch_threads": config.threads or torch.get_num_threads(),
        },
        "config": dataclasses.asdict(config),
        "method": method_description(config.device),
        "models": {label: model_description(s) for label, s in simulators.items()},
        "paper": {"table_1": PAPER_TABLE_1, "ratios_movi_b": PAPER_RATIOS_MOVI_B},
        "data": files,
    }


def model_description(simulator) -> dict:
    return {
        "architecture": architecture_of(simulator),
        "simulator_config": simulator.config.to_json(),
        "parameters": sum(p.numel() for p in simulator.parameters()),
        "model_mib": model_bytes(simulator) / MIB,
    }


def cpu_name() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux), else the machine type."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def environment(device) -> dict:
    device = torch.device(device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else cpu_name()
    return {
        "device": str(device),
        "device_name": name,
        "cpu_count": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
    }


def method_description(device) -> dict:
    return {
        "edges": "edges of each set of the step-t graph, face-face hyper-edges once per direction; mean ± std (ddof 1) over the sampled (trajectory, frame) pairs",
        "runtime": "wall-clock ms per phase (graph_ms: build_scene_graph; network_ms: graph copy to the device + network, no grad; step_ms: LearnedSimulator.step; train_step_ms: copy + forward + MSE + backward of one graph), models alternating, after warm-up; median and quartiles over pairs × repeats",
        "memory": MEMORY_METHOD[torch.device(device).type],
        "memory_scope": "the network part of one step (graph copy + forward) and of one training step (graph copy + forward + backward, gradients included); numpy memory of the graph builder and library scratch space are not torch tensors and are not counted",
        "memory_statistic": "mean ± std (ddof 1) over the sampled pairs",
    }


def markdown_report(result: dict) -> str:
    """The result as markdown: the main table, edges by type, ratios next to the paper's."""
    lines = (
        header_lines(result)
        + [""]
        + main_table(result)
        + [""]
        + edge_table(result)
        + [""]
        + ratio_table(result)
    )
    return "\n".join(lines) + "\n"


def header_lines(result: dict) -> list[str]:
    """What was measured, on what, and how memory was counted."""
    env, config = result["environment"], result["config"]
    lines = [
        f"Device: {env['device']} ({env['device_name']}), {env['torch_threads']} torch thread(s), torch {env['torch']}; {config['repeats']} timed repeats per pair after {config['warmup']} warm-up."
    ]
    for label, model in result["models"].items():
        settings = json.loads(model["simulator_config"])
        network, graph = settings["network"], settings["graph"]
        lines.append(
            f"{label}: latent {network['latent_size']}, {network['message_passing_steps']} message-passing steps, {model['parameters']} parameters ({model['model_mib']:.1f} MiB);"
            f" collision radius {graph['collision_radius']} m, max faces {settings['max_faces_per_object']}."
        )
    for label, data in result["data"].items():
        lines.append(
            f"{label}: {data['pairs']} (trajectory, frame) pairs, {data['pairs_in_contact']} in contact."
        )
    lines.append(f"Memory: {result['method']['memory']}.")
    return [line + "  " for line in lines[:-1]] + lines[-1:]


def _pm(stat, digits=1) -> str:
    return f"{stat['mean']:.{digits}f} ± {stat['std']:.{digits}f}"


def _iqr(stat) -> str:
    return f"{stat['median']:.1f} [{stat['q25']:.1f}, {stat['q75']:.1f}]"


def main_table(result: dict) -> list[str]:
    lines = [
        "| data | model | step memory MiB | step ms (median [IQR]) | graph ms | network ms | train-step memory MiB | train-step ms | edges |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for data_label, data in result["data"].items():
        for label, m in data["models"].items():
            t = m["times_ms"]
            lines.append(
                f"| {data_label} | {label} | {_pm(m['step_memory']['peak_mib'], 2)} | {_iqr(t['step_ms'])} | {_iqr(t['graph_ms'])} | {_iqr(t['network_ms'])}"
                f" | {_pm(m['train_memory']['peak_mib'], 2)} | {_iqr(t['train_step_ms'])} | {_pm(m['edges']['total'], 0)} |"
            )
    return lines


def edge_table(result: dict) -> list[str]:
    lines = [
        f"| data | model | {' | '.join(EDGE_TYPES)} | total | nodes |",
        "| --- | --- |" + " --- |" * (len(EDGE_TYPES) + 2),
    ]
    for data_label, data in result["data"].items():
        for label, m in data["models"].items():
            cells = [_pm(m["edges"][name], 0) for name in (*EDGE_TYPES, "total", "nodes")]
            lines.append(f"| {data_label} | {label} | {' | '.join(cells)} |")
    return lines


def ratio_table(result: dict) -> list[str]:
    paper = result["paper"]["ratios_movi_b"]
    lines = [
        "| FIGNet*/FIGNet | edges | step memory | train-step memory | step time | network time | train-step time |",
        "| --- | --- | --- | --- | --- | --- | --- |",
        f"| paper, MOVi-B | {paper['edges']:.2f} | {paper['memory_mib']:.2f} | – | {paper['runtime_ms']:.2f} | – | – |",
    ]
    for data_label, data in result["data"].items():
        r = data["ratios"]
        if r is not None:
            cells = [
                r[key]
                for key in ("edges", "step_memory", "train_memory", "step_time", "network_time", "train_time")
            ]
            lines.append(f"| {data_label} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    return lines
