import json
import weakref

import numpy as np
import pytest
import torch
from click.testing import CliRunner
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten

from fignetctl.bench import memory as benchmark
from fignetctl.cli import cli
from fignetctl.core.model.simulator import SimulatorConfig
from fignetctl.core.trajectory import write_trajectories
from tests.conftest import box_drop_file

MIB = 2**20
OTHER_EDGE_TYPES = ("mesh_to_object", "object_to_mesh", "face_face", "nodes")


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """One tiny run: a spinning box just above the floor (in contact range from frame 0)."""
    folder = tmp_path_factory.mktemp("bench")
    data = write_trajectories(folder / "box.h5", box_drop_file(frames=8, height=0.6))
    out = folder / "bench.json"
    args = [
        "bench-memory",
        str(data),
        "--size",
        "tiny",
        "--samples",
        "2",
        "--repeats",
        "2",
        "--json",
        str(out),
        "--markdown",
        str(folder / "bench.md"),
    ]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    return folder, data, json.loads(out.read_text()), result.output


def test_json_records_settings_method_and_models(bench):
    _, _data, result, _ = bench
    assert result["format"] == "fignetctl.bench-memory" and result["format_version"] == 1
    assert result["config"]["samples"] == 2 and result["config"]["repeats"] == 2
    assert "torch.profiler" in result["method"]["memory"]  # the CPU method is named
    assert {m["architecture"] for m in result["models"].values()} == {"FIGNet", "FIGNet*"}
    box = result["data"]["box"]
    assert box["pairs"] == 2 and box["pairs_in_contact"] == 2
    assert {s["frame"] for s in box["samples"]} <= set(range(2, 7))  # the middle of 8 frames
    assert len(box["sha256"]) == 64


def expected_node_node_edges(data_path, frame):
    """Both directions of the box's 18 edges and of the floor edges whose two vertices are in
    the graph (those of floor faces within the collision radius, found by brute force)."""
    from fignetctl.core.broadphase import brute_force_face_pairs
    from fignetctl.core.model.scene_data import EVALUATION_STATIC_REACH, scenes_from_file
    from fignetctl.core.model.scene_graph import GraphConfig, unique_undirected_edges

    scene = scenes_from_file(data_path, SimulatorConfig(max_faces_per_object=256), EVALUATION_STATIC_REACH)[0]
    geometry = scene.geometry
    triangles = geometry.world_vertices(scene.positions[frame], scene.quaternions[frame])[geometry.faces]
    pair_i, pair_j = brute_force_face_pairs(
        triangles, geometry.face_object, GraphConfig().collision_radius, geometry.static
    )
    floor_faces = [f for f in np.concatenate([pair_i, pair_j]) if geometry.static[geometry.face_object[f]]]
    floor_vertices = set(geometry.faces[floor_faces].ravel().tolist())
    floor_edges = unique_undirected_edges(geometry.faces[geometry.face_object == 0])
    in_graph = sum(1 for a, b in floor_edges if a in floor_vertices and b in floor_vertices)
    return 2 * (18 + in_graph)


def test_only_node_node_edges_differ(bench):
    _, data, result, _ = bench
    models = result["data"]["box"]["models"]
    full, star = models["FIGNet"]["edges"], models["FIGNet*"]["edges"]
    assert star["node_node"] == {"mean": 0.0, "std": 0.0}
    assert full["face_face"]["mean"] > 0
    for name in OTHER_EDGE_TYPES:
        assert full[name] == star[name], name
    assert full["total"]["mean"] == star["total"]["mean"] + full["node_node"]["mean"]
    for sample in result["data"]["box"]["samples"]:
        assert sample["FIGNet*"]["edges"]["node_node"] == 0
        assert sample["FIGNet"]["edges"]["node_node"] == expected_node_node_edges(data, sample["frame"]) > 36


def test_memory_and_times_are_positive_and_memory_includes_the_model(bench):
    _, _, result, _ = bench
    for label, model in result["data"]["box"]["models"].items():
        model_mib = result["models"][label]["model_mib"]
        for kind in ("step_memory", "train_memory"):
            assert model["step_memory"]["peak_mib"]["mean"] > model_mib
            above = model[kind]["profiler_peak_above_model_mib"]["mean"]
            assert model[kind]["peak_mib"]["mean"] == pytest.approx(model_mib + above)
        assert (
            model["train_memory"]["peak_mib"]["mean"] > model["step_memory"]["peak_mib"]["mean"]
        )  # activations kept for backward
        for phase in benchmark.TIMINGS:
            stat = model["times_ms"][phase]
            assert stat["n"] == 4 and 0 < stat["q25"] <= stat["median"] <= stat["q75"] < 60_000


def test_ratios_follow_the_summaries_and_markdown_shows_them(bench):
    folder, _, result, output = bench
    box = result["data"]["box"]
    star, full = box["models"]["FIGNet*"], box["models"]["FIGNet"]
    ratios = box["ratios"]
    assert ratios["edges"] == pytest.approx(star["edges"]["total"]["mean"] / full["edges"]["total"]["mean"])
    assert ratios["step_memory"] == pytest.approx(
        star["step_memory"]["peak_mib"]["mean"] / full["step_memory"]["peak_mib"]["mean"]
    )
    assert ratios["train_memory"] == pytest.approx(
        star["train_memory"]["peak_mib"]["mean"] / full["train_memory"]["peak_mib"]["mean"]
    )
    assert ratios["step_time"] == pytest.approx(
        star["times_ms"]["step_ms"]["median"] / full["times_ms"]["step_ms"]["median"]
    )
    assert ratios["train_time"] == pytest.approx(
        star["times_ms"]["train_step_ms"]["median"] / full["times_ms"]["train_step_ms"]["median"]
    )
    assert 0 < ratios["edges"] < 1 and ratios["step_memory"] < 1  # no surface edges: fewer edges, less memory
    assert result["paper"]["ratios_movi_b"]["edges"] == pytest.approx(8630 / 24514)
    assert "| paper, MOVi-B | 0.35 | 0.79 | – | 0.74 |" in output
    assert f"| box | {ratios['edges']:.2f} | {ratios['step_memory']:.2f} |" in output
    assert (folder / "bench.md").read_text() == output


def test_refuses_existing_output_and_model_with_size(bench):
    folder, data, _, _ = bench
    result = CliRunner().invoke(cli, ["bench-memory", str(data), "--json", str(folder / "bench.json")])
    assert result.exit_code == 2 and "--overwrite" in result.output
    result = CliRunner().invoke(cli, ["bench-memory", str(data), "--model", str(data), "--size", "tiny"])
    assert result.exit_code == 2 and "--model" in result.output


@pytest.mark.parametrize("bad", ["garbage", "two_frames"])
def test_bad_data_is_one_line_error(tmp_path, bad):
    path = tmp_path / "bad.h5"
    if bad == "garbage":
        path.write_bytes(b"\x89HDF not really" * 20)
    else:
        write_trajectories(path, box_drop_file(frames=2))
    out = tmp_path / "bench.json"
    result = CliRunner().invoke(
        cli,
        ["bench-memory", str(path), "--size", "tiny", "--samples", "1", "--repeats", "1", "--json", str(out)],
    )
    assert result.exit_code == 1
    assert result.output.startswith("Error: ") and result.output.count("\n") == 1
    assert "Traceback" not in result.output and not out.exists()


def test_peak_of_running_sum_of_a_known_sequence():
    assert benchmark.peak_of_running_sum([0, 1, 2, 3, 4], [1, 2, -1, 3, -5]) == 5
    assert benchmark.peak_of_running_sum([3, 0, 2, 1], [-1, 4, 2, -4]) == 4  # ordered by time first
    assert benchmark.peak_of_running_sum([], []) == 0


def test_profiled_peak_of_known_allocations():
    def allocate():
        a = torch.empty(MIB, dtype=torch.uint8)
        b = torch.empty(2 * MIB, dtype=torch.uint8)
        del a
        c = torch.empty(MIB + MIB // 2, dtype=torch.uint8)
        return b, c

    assert benchmark.profiled_peak_bytes(allocate, "cpu") == 3 * MIB + MIB // 2


class LiveStorageBytes(TorchDispatchMode):
    """Independent reference: bytes of tensor storages created inside the block, peak of live."""

    def __init__(self, existing):
        super().__init__()
        self.live, self.peak = 0, 0
        self.seen = {t.untyped_storage().data_ptr() for t in existing}

    def _freed(self, key, nbytes):
        self.live -= nbytes
        self.seen.discard(key)

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for tensor in tree_flatten(out)[0]:
            if not isinstance(tensor, torch.Tensor):
                continue
            storage = tensor.untyped_storage()
            key, nbytes = storage.data_ptr(), storage.nbytes()
            if key not in self.seen and nbytes > 0:
                self.seen.add(key)
                self.live += nbytes
                self.peak = max(self.peak, self.live)
                weakref.finalize(storage, self._freed, key, nbytes)
        return out


def test_profiler_peak_equals_an_independent_live_tensor_count():
    from fignetctl.core.model.scene_data import Scene, scene_from_trajectory

    data = box_drop_file(frames=4, height=0.6)
    scene = scene_from_trajectory(data, "00000", SimulatorConfig(max_faces_per_object=256))
    assert isinstance(scene, Scene)
    simulators = benchmark.untrained_simulators("tiny", seed=3)
    with benchmark.torch_threads(1):
        check_profiler_against_reference(simulators, scene)


def check_profiler_against_reference(simulators, scene):
    for simulator in simulators.values():
        workload = benchmark.make_workload(simulator, scene, 1, torch.Generator().manual_seed(0), "cpu")
        benchmark.fit_normalizers(workload, "cpu")
        resident = [*simulator.parameters(), *simulator.buffers()]
        for run in (
            lambda: benchmark.run_network(workload, "cpu"),
            lambda: benchmark.run_training_step(workload, "cpu"),
        ):
            run()
            reference = LiveStorageBytes(resident)
            with reference:
                run()
            profiled = benchmark.profiled_peak_bytes(run, "cpu")
            assert profiled == reference.peak > 0


def test_frames_are_drawn_from_the_middle_and_in_contact_first():
    assert list(benchmark.middle_frames(3)) == [1]
    assert list(benchmark.middle_frames(121)) == list(range(30, 91))
    from fignetctl.core.model.scene_data import scene_from_trajectory

    far = scene_from_trajectory(
        box_drop_file(frames=12, height=5.0), "00000", SimulatorConfig(max_faces_per_object=256)
    )
    near = scene_from_trajectory(
        box_drop_file(frames=12, height=0.6), "00000", SimulatorConfig(max_faces_per_object=256)
    )
    pairs = benchmark.sample_frames([far, near], 3, np.random.default_rng(0), 0.2)
    assert [(i, contact) for i, _, contact in pairs] == [(1, True)] * 3
    pairs = benchmark.sample_frames([far], 2, np.random.default_rng(0), 0.2)
    assert len(pairs) == 2 and not any(contact for _, _, contact in pairs)
