"""Tiny synthetic data shared by the tests, made in the test (no downloads)."""

import os
from pathlib import Path

import numpy as np
import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):
    # `pytest -n 2` (make test) runs one worker per core: each worker's torch, and the commands
    # its tests start, use one thread, or the workers' thread pools fight over the cores.
    os.environ["OMP_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)


def pytest_collection_modifyitems(items):
    """The slow tests first: `pytest -n 2` then starts them while the quick ones fill the other
    worker, instead of leaving one running alone at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


SHARED = Path(__file__).resolve().parents[2] / "shared"
INDEPENDENT_FIXTURE = SHARED / "fixtures" / "independent-movi-b-v1.h5"


def box_drop_file(frames=3, dt=1 / 60, spin=3.0, height=2.0):
    """A unit box falling freely and spinning (rad/s about a tilted axis) above a static
    2-triangle floor, as a TrajectoryFile."""
    import trimesh

    from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile

    box = trimesh.creation.box()
    floor_vertices = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], np.float32)
    floor_faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    times = np.arange(frames) * dt
    positions = np.zeros((frames, 2, 3), np.float32)
    positions[:, 1, 2] = height - 0.5 * 10.0 * times**2
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    half_angles = 0.5 * spin * times
    quaternions = np.zeros((frames, 2, 4), np.float32)
    quaternions[:, 0, 0] = 1.0
    quaternions[:, 1, 0] = np.cos(half_angles)
    quaternions[:, 1, 1:] = np.sin(half_angles)[:, None] * axis
    velocities = np.zeros((frames, 2, 3), np.float32)
    velocities[:, 1, 2] = -10.0 * times
    angular_velocities = np.zeros((frames, 2, 3), np.float32)
    angular_velocities[:, 1] = spin * axis
    trajectory = Trajectory(
        mesh_names=np.array(["floor", "box"], dtype=object),
        scales=np.array([1.0, 1.0], np.float32),
        positions=positions,
        quaternions=quaternions,
        static=np.array([True, False]),
        mass=np.array([0.0, 1.0], np.float32),
        friction=np.array([0.3, 0.5], np.float32),
        restitution=np.array([0.5, 0.5], np.float32),
        velocities=velocities,
        angular_velocities=angular_velocities,
    )
    meshes = {
        "floor": Mesh(floor_vertices, floor_faces),
        "box": Mesh(np.asarray(box.vertices, np.float32), np.asarray(box.faces, np.int32)),
    }
    return TrajectoryFile(
        dt=dt, gravity=np.array([0, 0, -10.0]), meshes=meshes, trajectories={"00000": trajectory}
    )


def bouncing_box_file(frames=12, impact=6, speed=3.0):
    """box_drop_file's box without spin, coming down at `speed` m/s and bouncing back up at
    `speed` at frame `impact`, each way in free fall; poses and recorded velocities agree."""
    import dataclasses

    data = box_drop_file(frames=frames, spin=0.0, height=2.0)
    times = np.arange(frames) * data.dt
    trajectory = data.trajectories["00000"]
    positions = np.array(trajectory.positions)
    positions[:, 1, 2] = 2.0 + speed * data.dt * np.abs(np.arange(frames) - impact) - 5.0 * times**2
    velocities = np.zeros((frames, 2, 3), np.float32)
    velocities[:, 1, 2] = np.where(np.arange(frames) < impact, -speed, speed) - 10.0 * times
    trajectory = dataclasses.replace(trajectory, positions=positions, velocities=velocities)
    return dataclasses.replace(data, trajectories={"00000": trajectory})


@pytest.fixture
def box_drop():
    return box_drop_file()


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory):
    """render-views' tiny preset at 160x120, seed 0, no video: a capture folder with ground truth."""
    from fignetctl.core.synthetic_capture import PRESETS, capture_settings
    from fignetctl.stages.render_views import write_capture

    folder = tmp_path_factory.mktemp("capture") / "capture"
    write_capture(
        folder, capture_settings(**{**PRESETS["tiny"], "width": 160, "height": 120}, seed=0, video=False)
    )
    return folder
