"""The checkpoints shipped inside the package."""

import dataclasses

import numpy as np

from fignetctl.core.containers import WEIGHTS_HASH_KEY
from fignetctl.core.model.apply import load_model
from fignetctl.core.model.checkpoint import BUNDLED, bundled_model_path, read_checkpoint_payload
from fignetctl.core.model.rollout import rollout
from fignetctl.core.model.scene_data import scene_from_trajectory
from tests.conftest import box_drop_file


def test_bundled_checkpoints_are_small_and_differ_only_in_surface_edges():
    configs = {}
    for name in BUNDLED:
        path = bundled_model_path(name)
        assert path.stat().st_size < 5 * 2**20
        payload = read_checkpoint_payload(path)  # checks the weights against their checksum
        assert "training_state" not in payload and payload.get(WEIGHTS_HASH_KEY)
        configs[name] = load_model(name).config
    star, full = configs["fignet-star-movi-b"], configs["fignet-movi-b"]
    assert not star.graph.surface_edges and full.graph.surface_edges
    assert dataclasses.replace(full, graph=star.graph) == star


def test_default_model_rolls_a_box_dropped_on_the_floor_out_finitely():
    simulator = load_model()
    data = box_drop_file(frames=3, dt=1 / 30, height=0.8)
    scene = scene_from_trajectory(data, "00000", simulator.config)
    positions, quaternions = rollout(simulator, scene, 30)
    assert np.isfinite(positions).all() and np.isfinite(quaternions).all()
    assert np.abs(positions[:, 1] - positions[1, 1]).max() < 5.0  # nothing flies off
