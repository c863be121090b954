"""benchmarks/block_scales.py: the scales it reads off a network's processor blocks."""

import types

import pytest
import torch

from fignetctl.core.model.network import EncodeProcessDecode, NetworkConfig, silence
from fignetctl.core.model.scene_graph import GraphConfig, graph_signature_for
from tests.bench import load_benchmark

block_scales = load_benchmark("block_scales")


def test_a_silenced_block_reads_zero_and_the_others_what_their_layer_norms_hold():
    config = NetworkConfig(latent_size=8, mlp_hidden_size=8, mlp_hidden_layers=1, message_passing_steps=3)
    network = EncodeProcessDecode(config, graph_signature_for(GraphConfig()))
    silence(network.processor[2])
    with torch.no_grad():  # block 1's node update: scale 0.5 on half its width, shift 0.25
        norm = network.processor[1].node_update[1].layer_norm
        norm.weight[: norm.weight.numel() // 2] = 0.5
        norm.bias.fill_(-0.25)
    blocks = block_scales.block_scales(types.SimpleNamespace(network=network))
    assert len(blocks) == 3
    assert set(blocks[0]) == {"node_update"} | {
        f"edge_updates.{name}" for name in network.signature.edge_feature_sizes
    }
    assert all(u == {"scale": 1.0, "shift": 0.0} for u in blocks[0].values())  # as built
    assert blocks[1]["node_update"] == {"scale": 0.75, "shift": 0.25}
    assert all(u == {"scale": 0.0, "shift": 0.0} for u in blocks[2].values())


def test_a_file_that_is_not_a_model_is_one_line_of_error(tmp_path, monkeypatch):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    monkeypatch.setattr("sys.argv", ["block_scales.py", str(bad)])
    with pytest.raises(SystemExit, match="not a readable fignetctl model file"):
        block_scales.main()
