"""benchmarks/pair_average.py: the bundled pair averaged in weight space and in their answers."""

import torch

from fignetctl.core.model.apply import load_model
from fignetctl.core.model.checkpoint import bundled_model_path, save_torch_payload
from fignetctl.core.model.graph import NODE_NODE, MultiGraph
from fignetctl.core.model.scene_graph import build_scene_graph
from tests.bench import load_benchmark
from tests.core.model.test_rotations import _stones_on_floor

pair_average = load_benchmark("pair_average")
PATHS = bundled_model_path("fignet-movi-b"), bundled_model_path("fignet-star-movi-b")


def _graph(simulator):
    """The stones' graph as the FIGNet builds it (with surface edges), in contact with the floor."""
    geometry, positions, quaternions = _stones_on_floor()
    graph = build_scene_graph(geometry, positions, quaternions, simulator.config.graph).graph
    assert graph.edge_sets[NODE_NODE].num_edges > 0
    return graph


def _without_surface_edges(graph):
    return MultiGraph(graph.node_features, {k: v for k, v in graph.edge_sets.items() if k != NODE_NODE})


def test_a_soup_at_either_end_is_that_model(tmp_path):
    """All FIGNet: the FIGNet's answers. All FIGNet*: its zero columns shut the surface-edge
    messages out, so the soup answers as the FIGNet* does; half way it is neither."""
    fignet, star = load_model("fignet-movi-b"), load_model("fignet-star-movi-b")
    graph = _graph(fignet)
    with torch.no_grad():
        answers = {}
        for weight in (0.0, 0.5, 1.0):
            save_torch_payload(tmp_path / f"{weight}.pt", pair_average.soup_payload(*PATHS, weight))
            answers[weight] = load_model(str(tmp_path / f"{weight}.pt")).network_acceleration(graph)
        torch.testing.assert_close(answers[0.0], fignet.network_acceleration(graph), atol=1e-6, rtol=0)
        expected = star.network_acceleration(_without_surface_edges(graph))
        torch.testing.assert_close(answers[1.0], expected, atol=1e-5, rtol=1e-5)
        assert (answers[0.5] - answers[0.0]).abs().max() > 1e-3
        assert (answers[0.5] - answers[1.0]).abs().max() > 1e-3


def test_the_ensemble_answers_with_the_mean_of_both():
    fignet, star = load_model("fignet-movi-b"), load_model("fignet-star-movi-b")
    graph = _graph(fignet)
    with torch.no_grad():
        own = fignet.network_acceleration(graph)
        other = star.network_acceleration(_without_surface_edges(graph))
        averaged = pair_average.ensemble(fignet, star).network_acceleration(graph)
    torch.testing.assert_close(averaged, 0.5 * (own + other), atol=1e-6, rtol=0)
    assert (own - other).abs().max() > 1e-3  # the two differ, so the mean is neither
