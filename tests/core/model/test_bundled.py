"""The checkpoints shipped inside the package."""

import dataclasses

import numpy as np

from fignetctl.core import movi
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
    movi_b = movi.movi_config("movi-b")  # what they were trained on: make-dataset --preset movi-b
    assert star.dt == movi_b.dt and star.gravity == tuple(movi_b.gravity)


def test_default_model_rolls_a_box_dropped_on_the_floor_out_finitely():
    simulator = load_model()
    data = box_drop_file(frames=3, dt=1 / 30, height=0.8)
    scene = scene_from_trajectory(data, "00000", simulator.config)
    positions, quaternions = rollout(simulator, scene, 30)
    assert np.isfinite(positions).all() and np.isfinite(quaternions).all()
    assert np.abs(positions[:, 1] - positions[1, 1]).max() < 5.0  # nothing flies off


def test_make_checkpoints_trains_the_bundled_models_settings():
    """`make checkpoints` reproduces the bundled models only if its flags give every setting in
    which they differ from `train`'s defaults: its last stage's flags must build their config."""
    import shlex
    import shutil
    import subprocess
    from pathlib import Path

    import pytest

    from fignetctl.commands import options
    from fignetctl.commands.train import train
    from fignetctl.stages import train as stage

    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    root = Path(__file__).resolve().parents[3]
    printed = subprocess.run(
        ["make", "-n", "--no-print-directory", "checkpoints", "DATA=/nonexistent"],
        cwd=root,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    last_stage = {}
    for line in printed.splitlines():
        words = shlex.split(line)
        if len(words) > 2 and words[0].endswith("fignetctl") and words[1] == "train":
            output = words[words.index("-o") + 1]
            last_stage[Path(output).stem.removesuffix("-tuned").removesuffix("-base")] = words[2:]
    assert sorted(last_stage) == sorted(BUNDLED)
    for name, arguments in last_stage.items():
        values = train.make_context("train", arguments).params
        settings = options.settings_from(stage.Settings, values)
        config, training = stage.configs(settings)
        bundled = load_model(name).config
        assert dataclasses.replace(config, dt=bundled.dt, gravity=bundled.gravity) == bundled, name
        assert training.precision == "fp32" and training.frame_sampling == "uniform"
