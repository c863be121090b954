import dataclasses

import pytest
import torch

from fignetctl.core.model.graph import (
    FACE_FACE,
    MESH_TO_OBJECT,
    NODE_NODE,
    OBJECT_TO_MESH,
    EdgeSet,
    GraphSignature,
    MultiGraph,
    batch_graphs,
    graph_signature,
)
from fignetctl.core.model.network import (
    PRESETS,
    EncodeProcessDecode,
    Incidence,
    concatenated_forward,
    mlp_widened,
    sum_messages_into_receivers,
)

NODE_FEATURE_SIZE = 5
EDGE_FEATURE_SIZES = {MESH_TO_OBJECT: 4, OBJECT_TO_MESH: 4, NODE_NODE: 4, FACE_FACE: 7}
TINY = PRESETS["tiny"]


def random_edge_set(name, num_edges, num_nodes, generator):
    index_shape = (num_edges, 3) if name == FACE_FACE else (num_edges,)
    return EdgeSet(
        name=name,
        features=torch.randn(num_edges, EDGE_FEATURE_SIZES[name], generator=generator),
        senders=torch.randint(num_nodes, index_shape, generator=generator),
        receivers=torch.randint(num_nodes, index_shape, generator=generator),
    )


def random_graph(num_nodes, num_edges, seed=0):
    """num_edges : edge set name -> count; the graph has exactly those edge sets."""
    generator = torch.Generator().manual_seed(seed)
    edge_sets = {
        name: random_edge_set(name, count, num_nodes, generator) for name, count in num_edges.items()
    }
    return MultiGraph(torch.randn(num_nodes, NODE_FEATURE_SIZE, generator=generator), edge_sets)


def four_node_graph():
    """Mesh nodes 0, 1, 2 (one triangle) and object node 3; a face–face edge from the
    triangle onto itself stands in for a collision."""
    generator = torch.Generator().manual_seed(1)
    mesh, objects = torch.tensor([0, 1, 2]), torch.tensor([3, 3, 3])
    ring_senders, ring_receivers = (
        torch.tensor([0, 1, 2, 1, 2, 0]),
        torch.tensor([1, 2, 0, 0, 1, 2]),
    )
    index_pairs = {
        MESH_TO_OBJECT: (mesh, objects),
        OBJECT_TO_MESH: (objects, mesh),
        NODE_NODE: (ring_senders, ring_receivers),
        FACE_FACE: (torch.tensor([[0, 1, 2]]), torch.tensor([[2, 0, 1]])),
    }
    edge_sets = {
        name: EdgeSet(name, torch.randn(len(s), EDGE_FEATURE_SIZES[name], generator=generator), s, r)
        for name, (s, r) in index_pairs.items()
    }
    return MultiGraph(torch.randn(4, NODE_FEATURE_SIZE, generator=generator), edge_sets)


def tiny_model_for(graph, seed=0, **config_changes):
    torch.manual_seed(seed)
    config = dataclasses.replace(TINY, **config_changes)
    return EncodeProcessDecode.for_graph(config, graph)


ALL_SETS = {MESH_TO_OBJECT: 12, OBJECT_TO_MESH: 12, NODE_NODE: 20, FACE_FACE: 6}


def test_forward_on_four_node_graph_gives_finite_per_node_output():
    graph = four_node_graph()
    output = tiny_model_for(graph)(graph)
    assert output.shape == (4, 3)
    assert torch.isfinite(output).all()


def test_paper_preset_has_the_paper_sizes():
    paper = PRESETS["paper"]
    assert (paper.latent_size, paper.mlp_hidden_layers, paper.mlp_hidden_size) == (128, 2, 128)
    assert (paper.message_passing_steps, paper.output_size) == (10, 3)
    assert PRESETS["tiny"].latent_size < PRESETS["small"].latent_size < paper.latent_size


def test_node_that_receives_nothing_keeps_its_row_and_depends_only_on_itself():
    graph = random_graph(8, ALL_SETS)
    isolated = 8  # a ninth node, the largest index, in no edge at all
    features = torch.cat([graph.node_features, torch.randn(1, NODE_FEATURE_SIZE)])
    graph_with_isolated_node = MultiGraph(features, graph.edge_sets)
    model = tiny_model_for(graph)
    output = model(graph_with_isolated_node)
    alone = MultiGraph(features[isolated:], {name: random_edge_set(name, 0, 1, None) for name in ALL_SETS})
    assert output.shape == (9, 3)
    torch.testing.assert_close(output[isolated], model(alone)[0])
    torch.testing.assert_close(output[:isolated], model(graph))


def test_batched_graphs_give_the_same_outputs_as_separate_graphs():
    first = random_graph(7, ALL_SETS, seed=1)
    second = random_graph(11, {MESH_TO_OBJECT: 5, OBJECT_TO_MESH: 9, NODE_NODE: 0, FACE_FACE: 3}, seed=2)
    model = tiny_model_for(first)
    batched = model(batch_graphs([first, second]))
    separate = torch.cat([model(first), model(second)])
    torch.testing.assert_close(batched, separate, atol=1e-5, rtol=1e-5)


def test_batch_graphs_offsets_indices_by_earlier_node_counts():
    first, second = random_graph(7, ALL_SETS, seed=1), random_graph(11, ALL_SETS, seed=2)
    batched = batch_graphs([first, second])
    assert batched.num_nodes == 18
    face_face = batched.edge_sets[FACE_FACE]
    torch.testing.assert_close(face_face.receivers[6:], second.edge_sets[FACE_FACE].receivers + 7)
    torch.testing.assert_close(face_face.senders[:6], first.edge_sets[FACE_FACE].senders)
    with pytest.raises(ValueError, match="disagree on edge sets"):
        batch_graphs([first, random_graph(3, {MESH_TO_OBJECT: 2})])


def test_permuting_nodes_permutes_the_output():
    graph = random_graph(10, ALL_SETS, seed=3)
    permutation = torch.randperm(10, generator=torch.Generator().manual_seed(4))
    new_index_of_old = torch.empty_like(permutation)
    new_index_of_old[permutation] = torch.arange(10)
    edge_sets = {
        name: EdgeSet(name, es.features, new_index_of_old[es.senders], new_index_of_old[es.receivers])
        for name, es in graph.edge_sets.items()
    }
    permuted = MultiGraph(graph.node_features[permutation], edge_sets)
    model = tiny_model_for(graph)
    torch.testing.assert_close(model(permuted), model(graph)[permutation], atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("edge_sets", [ALL_SETS, {MESH_TO_OBJECT: 12, OBJECT_TO_MESH: 12, FACE_FACE: 40}])
def test_forward_without_concatenations_equals_the_mlps_on_concatenated_inputs(edge_sets):
    graph = random_graph(9, edge_sets, seed=3)  # 40 face–face edges on 9 nodes: nodes repeat
    model = tiny_model_for(graph, mlp_hidden_layers=1)
    fast = model(graph)
    fast.square().sum().backward()
    fast_gradients = {name: p.grad.clone() for name, p in model.named_parameters()}
    model.zero_grad()
    reference = concatenated_forward(model, graph)
    reference.square().sum().backward()
    torch.testing.assert_close(fast, reference, rtol=1e-5, atol=1e-6)
    for name, p in model.named_parameters():
        torch.testing.assert_close(fast_gradients[name], p.grad, rtol=1e-4, atol=1e-5, msg=name)


def test_incidence_projects_each_node_once_and_gathers_it_per_edge_part():
    generator = torch.Generator().manual_seed(2)
    node_latents = torch.randn(6, 4, generator=generator)
    faces = torch.tensor([[5, 1, 1], [1, 5, 3]])
    weight = torch.randn(2, 3 * 4, generator=generator)
    incidence = Incidence.of(faces)
    assert incidence.nodes.tolist() == [1, 3, 5] and incidence.parts == 3
    expected = torch.cat([node_latents[faces[:, k]] for k in range(3)], dim=1) @ weight.T
    torch.testing.assert_close(incidence.gathered_projection(node_latents, weight), expected)


def test_hyper_edge_messages_go_to_their_own_receiver_vertex():
    messages = torch.arange(2 * 3 * 2, dtype=torch.float32).reshape(2, 3, 2)
    receivers = torch.tensor([[4, 0, 2], [2, 5, 1]])
    summed = sum_messages_into_receivers(messages, receivers, num_nodes=7)
    expected = torch.zeros(7, 2)
    expected[[4, 0, 2]] += messages[0]
    expected[[2, 5, 1]] += messages[1]
    torch.testing.assert_close(summed, expected)
    assert summed.shape == (7, 2)  # nodes 3 and 6 receive nothing and are still there


def zero_message_part(part, latent_size):
    def hook(module, inputs, output):
        output = output.clone()
        output[:, part * latent_size : (part + 1) * latent_size] = 0
        return output

    return hook


@pytest.mark.parametrize("part", [0, 1, 2])
def test_each_face_face_message_part_reaches_only_its_receiver_vertex(part):
    generator = torch.Generator().manual_seed(5)
    face_face = EdgeSet(
        FACE_FACE,
        torch.randn(1, 7, generator=generator),
        torch.tensor([[0, 1, 2]]),
        torch.tensor([[5, 3, 4]]),
    )
    graph = MultiGraph(torch.randn(6, NODE_FEATURE_SIZE, generator=generator), {FACE_FACE: face_face})
    model = tiny_model_for(graph, message_passing_steps=1)
    before = model(graph)
    model.processor[0].edge_updates[FACE_FACE].register_forward_hook(
        zero_message_part(part, TINY.latent_size)
    )
    changed = (model(graph) - before).abs().amax(dim=1) > 1e-6
    assert changed.nonzero().flatten().tolist() == [[5, 3, 4][part]]


def test_fignet_star_network_has_no_node_node_weights_and_uses_all_it_has():
    star_sets = {MESH_TO_OBJECT: 12, OBJECT_TO_MESH: 12, FACE_FACE: 6}
    graph = random_graph(8, star_sets)
    model = tiny_model_for(graph)
    assert not [name for name, _ in model.named_parameters() if NODE_NODE in name]
    model(graph).square().sum().backward()
    unused = [name for name, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert unused == []
    with pytest.raises(ValueError, match="built for edge sets"):
        model(random_graph(8, ALL_SETS))


def test_empty_face_face_set_gives_finite_outputs_and_gradients():
    graph = random_graph(8, {**ALL_SETS, FACE_FACE: 0})
    assert graph.edge_sets[FACE_FACE].senders.shape == (0, 3)
    model = tiny_model_for(graph)
    output = model(graph)
    output.square().sum().backward()
    assert output.shape == (8, 3) and torch.isfinite(output).all()
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)
    assert graph_signature(graph).hyper_edge_set_names == (FACE_FACE,)


def test_processor_blocks_have_their_own_weights():
    model = tiny_model_for(four_node_graph())
    first, second = (
        model.processor[0].node_update[0][0].weight,
        model.processor[1].node_update[0][0].weight,
    )
    assert first.data_ptr() != second.data_ptr()
    assert not torch.equal(first, second)


def test_edge_set_with_mismatched_shapes_is_refused():
    with pytest.raises(ValueError, match="face_face"):
        EdgeSet(
            FACE_FACE,
            torch.zeros(2, 7),
            torch.zeros(2, 2, dtype=torch.long),
            torch.zeros(2, 2, dtype=torch.long),
        )
    with pytest.raises(ValueError, match="torch.long"):
        EdgeSet(NODE_NODE, torch.zeros(2, 4), torch.zeros(2), torch.zeros(2))


def test_signature_survives_a_plain_dict_round_trip():
    signature = graph_signature(four_node_graph())
    assert GraphSignature(**signature.as_dict()) == signature
    assert signature.edge_set_names == tuple(sorted(EDGE_FEATURE_SIZES))


def test_tiny_model_overfits_a_fixed_random_target():
    graph = random_graph(12, ALL_SETS, seed=6)
    target = torch.randn(12, 3, generator=torch.Generator().manual_seed(7))
    model = tiny_model_for(graph)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(100):
        optimizer.zero_grad()
        loss = (model(graph) - target).square().mean()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < losses[0] / 10


@pytest.mark.parametrize("hidden_layers", [1, 2, 3])
def test_a_network_widened_computes_what_it_did_and_then_learns_with_its_added_units(hidden_layers):
    graph = random_graph(num_nodes=30, num_edges=ALL_SETS, seed=3)
    narrow = tiny_model_for(graph, seed=1, mlp_hidden_layers=hidden_layers)
    wide = tiny_model_for(graph, seed=2, mlp_hidden_layers=hidden_layers, mlp_hidden_size=45)
    wide.load_state_dict(mlp_widened(narrow.state_dict(), wide.state_dict()))
    torch.testing.assert_close(wide(graph), narrow(graph), rtol=1e-5, atol=1e-6)
    wide(graph).square().sum().backward()
    added_columns = wide.decoder[-1].weight.grad[:, TINY.mlp_hidden_size :]
    assert added_columns.abs().max() > 0  # zero weights out of the added units, with gradients
    with pytest.raises(ValueError, match="does not fit"):
        mlp_widened(wide.state_dict(), narrow.state_dict())
