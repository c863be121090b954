"""Readers given truncated or corrupted files end in FormatError, never another exception."""

import numpy as np
import pytest

from fignetctl.core.model.checkpoint import load_checkpoint, save_checkpoint
from fignetctl.core.model.network import PRESETS
from fignetctl.core.model.scene_graph import GraphConfig
from fignetctl.core.model.simulator import LearnedSimulator, SimulatorConfig
from fignetctl.core.trajectory import read_trajectories, write_trajectories
from fignetctl.errors import FormatError
from tests.conftest import box_drop_file


def _damaged_copies(original: bytes, rng, count):
    """Truncations at random lengths and copies with random bytes overwritten."""
    for _ in range(count):
        cut = int(rng.integers(0, len(original)))
        yield original[:cut]
        damaged = np.frombuffer(original, np.uint8).copy()
        spots = rng.integers(0, len(original), size=int(rng.integers(1, 64)))
        damaged[spots] = rng.integers(0, 256, size=len(spots), dtype=np.uint8)
        yield damaged.tobytes()


def _accepts_or_refuses_clearly(reader, path):
    try:
        reader(path)
    except FormatError as error:
        assert str(error).startswith(str(path)) and "\n" not in str(error)


def test_trajectory_reader_on_damaged_files(tmp_path):
    original = write_trajectories(tmp_path / "t.h5", box_drop_file(frames=6), compression=None).read_bytes()
    rng = np.random.default_rng(0)
    for index, content in enumerate(_damaged_copies(original, rng, 60)):
        path = tmp_path / f"damaged-{index}.h5"
        path.write_bytes(content)
        _accepts_or_refuses_clearly(read_trajectories, path)


def test_model_reader_on_damaged_files(tmp_path):
    simulator = LearnedSimulator(SimulatorConfig(network=PRESETS["tiny"], graph=GraphConfig(0.1)))
    original = save_checkpoint(tmp_path / "m.pt", simulator).read_bytes()
    rng = np.random.default_rng(1)
    for index, content in enumerate(_damaged_copies(original, rng, 40)):
        path = tmp_path / f"damaged-{index}.pt"
        path.write_bytes(content)
        _accepts_or_refuses_clearly(load_checkpoint, path)


@pytest.mark.parametrize("content", [b"", b"\x00" * 10, b"PK\x03\x04" + b"\x00" * 100])
def test_tiny_garbage_is_refused(tmp_path, content):
    for reader, suffix in ((read_trajectories, ".h5"), (load_checkpoint, ".pt")):
        path = tmp_path / f"garbage{suffix}"
        path.write_bytes(content)
        with pytest.raises(FormatError):
            reader(path)
