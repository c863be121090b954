"""Hard cases for the bundled FIGNet* itself: rest, stacks, rods, thin plates, tiny and huge
objects, long rollouts. Each asserts finite values and an error bound against the exact answer
(where a resting object must end up) with the tolerance stated in the test.

The scenes use the materials the bundled models were trained on (MOVi-B: moving objects
rubber, friction 0.8, restitution 0.7; the floor 0.3, 0.5), as `build-graph` does by default;
docs/stability.md has what other values do. FIGNET_TEST_MODEL=path runs them on another
checkpoint, FIGNET_TEST_ROTATIONS=K with the network averaged over K turns about gravity."""

import numpy as np
import pytest
import trimesh

from fignetctl.core.model.apply import load_model, rollout_trajectory
from fignetctl.core.scene_building import ACTIVE, PASSIVE
from fignetctl.core.trajectory import Mesh, Trajectory, TrajectoryFile, read_trajectories, write_trajectories

pytestmark = pytest.mark.stability

DT = 1 / 30
FLOOR = trimesh.creation.box([40.0, 40.0, 1.0])  # top at z = 0 once placed at z = -0.5


@pytest.fixture(scope="module")
def model():
    import os

    simulator = load_model(os.environ.get("FIGNET_TEST_MODEL"))
    if "FIGNET_TEST_ROTATIONS" in os.environ:  # else the model file's own (1 unless it records more)
        simulator.rotations = int(os.environ["FIGNET_TEST_ROTATIONS"])
    return simulator


def scene_file(path, bodies, statics=()):
    """A 2-frame scene: `bodies` are (mesh, position, velocity) of moving objects (identity
    rotation); `statics` are (mesh, position) besides the floor. Properties: build-graph's
    defaults (MOVi-B's rubber moving, MOVi-B's floor static)."""
    meshes = {"floor": FLOOR}
    names, positions, velocities, static = ["floor"], [[0, 0, -0.5]], [[0, 0, 0]], [True]
    for index, (mesh, position) in enumerate(statics):
        meshes[f"static{index}"] = mesh
        (
            names.append(f"static{index}"),
            positions.append(position),
            velocities.append([0, 0, 0]),
            static.append(True),
        )
    for index, (mesh, position, velocity) in enumerate(bodies):
        meshes[f"body{index}"] = mesh
        (
            names.append(f"body{index}"),
            positions.append(position),
            velocities.append(velocity),
            static.append(False),
        )
    now = np.array(positions, np.float64)
    before = now - np.array(velocities, np.float64) * DT
    count = len(names)
    trajectory = Trajectory(
        mesh_names=np.array(names, dtype=object),
        scales=np.ones(count, np.float32),
        positions=np.stack([before, now]).astype(np.float32),
        quaternions=np.tile(np.array([1, 0, 0, 0], np.float32), (2, count, 1)),
        static=np.array(static),
        mass=np.where(static, 0.0, ACTIVE.mass).astype(np.float32),
        friction=np.where(static, PASSIVE.friction, ACTIVE.friction).astype(np.float32),
        restitution=np.where(static, PASSIVE.restitution, ACTIVE.restitution).astype(np.float32),
    )
    file_meshes = {
        name: Mesh(np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32))
        for name, m in meshes.items()
    }
    write_trajectories(path, TrajectoryFile(DT, np.array([0, 0, -9.81]), file_meshes, {"0": trajectory}))
    return path


def roll(model, path, steps, **options):
    """The model's rollout of a scene file, with free flight and the keep-out guard as
    `fignetctl rollout` has them."""
    result = rollout_trajectory(
        model, read_trajectories(path), steps, free_flight=True, keep_out=True, **options
    )
    trajectory = result.trajectories["0"]
    assert np.isfinite(trajectory.positions).all() and np.isfinite(trajectory.quaternions).all()
    return trajectory


def lowest_z(trajectory, meshes, frame):
    from fignetctl.core.transforms import transform_points

    return min(
        transform_points(
            meshes[name].vertices, scale, trajectory.positions[frame, o], trajectory.quaternions[frame, o]
        )[:, 2].min()
        for o, (name, scale, static) in enumerate(
            zip(trajectory.mesh_names, trajectory.scales, trajectory.static)
        )
        if not static
    )


def test_a_box_resting_on_the_floor_stays_put_for_500_steps(model, tmp_path):
    """Exact answer: it does not move. Bound: 1 cm (sleeping on, as `rollout --sleep`)."""
    path = scene_file(tmp_path / "rest.h5", [(trimesh.creation.box([1, 1, 1]), [0, 0, 0.5], [0, 0, 0])])
    trajectory = roll(model, path, 500, sleep=True)
    drift = np.linalg.norm(trajectory.positions[:, 1] - trajectory.positions[1, 1], axis=1).max()
    assert drift < 0.01, f"drift {drift:.4f} m"


def test_a_stack_of_three_boxes_stands(model, tmp_path):
    """Exact answer: the stack stands. Bound: no box moves more than 10 cm in 200 steps."""
    box = trimesh.creation.box([1, 1, 1])
    path = scene_file(tmp_path / "stack.h5", [(box, [0, 0, 0.5 + k], [0, 0, 0]) for k in range(3)])
    trajectory = roll(model, path, 200, sleep=True)
    moved = np.linalg.norm(trajectory.positions[:, 1:] - trajectory.positions[1, 1:], axis=2).max()
    assert moved < 0.10, f"a box moved {moved:.3f} m"


def test_a_thin_rod_lands_and_lies_on_the_floor(model, tmp_path):
    """A 2 m x 5 cm rod dropped flat from 0.5 m. Exact answer at rest: centre at z = 2.5 cm.
    Bound: within 10 cm of that after 120 steps, never more than 5 cm into the floor."""
    path = scene_file(
        tmp_path / "rod.h5", [(trimesh.creation.box([2.0, 0.05, 0.05]), [0, 0, 0.5], [0, 0, 0])]
    )
    trajectory = roll(model, path, 120)
    meshes = {
        name: m for name, m in zip(["floor", "body0"], [FLOOR, trimesh.creation.box([2.0, 0.05, 0.05])])
    }
    deepest = min(lowest_z(trajectory, meshes, frame) for frame in range(trajectory.num_frames))
    assert deepest > -0.05, f"{-deepest:.3f} m into the floor"
    assert abs(trajectory.positions[-1, 1, 2] - 0.025) < 0.10


def test_a_fast_box_does_not_tunnel_through_a_thin_plate(model, tmp_path):
    """A 0.5 m box at 8 m/s (0.27 m per frame) onto a static 2 cm plate at z = 1 m: it must end
    above the plate (no tunnelling), its lowest point never more than 10 cm through it."""
    plate = trimesh.creation.box([3.0, 3.0, 0.02])
    box = trimesh.creation.box([0.5, 0.5, 0.5])
    path = scene_file(
        tmp_path / "plate.h5", [(box, [0, 0, 2.0], [0, 0, -8.0])], statics=[(plate, [0, 0, 0.99])]
    )
    trajectory = roll(model, path, 40)
    meshes = {"floor": FLOOR, "static0": plate, "body0": box}
    deepest = min(lowest_z(trajectory, meshes, frame) for frame in range(trajectory.num_frames))
    assert deepest > 1.0 - 0.10, f"lowest point at z = {deepest:.3f} m (plate top at 1.0 m)"
    assert trajectory.positions[-1, 2, 2] > 1.0


@pytest.mark.parametrize("size", [0.02, 5.0])
def test_tiny_and_huge_boxes_land_at_their_rest_height(model, tmp_path, size):
    """A cube of 2 cm or 5 m dropped from one size above the floor, simulated at the model's
    size (--sim-scale auto). Exact answer at rest: centre at size / 2. Bound: within 20 % of the
    size after 1.5 s, never more than 10 % of the size into the floor."""
    box = trimesh.creation.box([size] * 3)
    path = scene_file(tmp_path / "cube.h5", [(box, [0, 0, 1.5 * size], [0, 0, 0])])
    steps = int(round(1.5 / (DT / np.sqrt(2.1 / size))))
    trajectory = roll(model, path, steps, sim_scale="auto")
    meshes = {"floor": FLOOR, "body0": box}
    deepest = min(lowest_z(trajectory, meshes, frame) for frame in range(trajectory.num_frames))
    assert deepest > -0.1 * size
    assert abs(trajectory.positions[-1, 1, 2] - size / 2) < 0.2 * size


def test_a_1000_step_rollout_stays_finite_and_above_the_floor(model, tmp_path):
    """Three objects thrown together, 1000 steps (33 s). Bound: finite, no object more than
    10 cm into the floor, all within 50 m of the origin."""
    bodies = [
        (trimesh.creation.box([1, 1, 1]), [-2, 0, 2], [3, 0, 0]),
        (trimesh.creation.icosphere(2, 0.6), [2, 0, 1.5], [-3, 0.5, 0]),
        (trimesh.creation.cylinder(0.4, 1.2), [0, 2, 2.5], [0, -2, 0]),
    ]
    path = scene_file(tmp_path / "long.h5", bodies)
    trajectory = roll(model, path, 1000, sleep=True)
    meshes = {"floor": FLOOR, **{f"body{k}": m for k, (m, _, _) in enumerate(bodies)}}
    deepest = min(lowest_z(trajectory, meshes, frame) for frame in range(0, trajectory.num_frames, 10))
    assert deepest > -0.10, f"{-deepest:.3f} m into the floor"
    assert np.abs(trajectory.positions[:, 1:]).max() < 50.0
