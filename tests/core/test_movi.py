"""MOVi-style scenes: settings, mass properties, seeds and shards, filters, and the physics.

Shapes are made here from trimesh primitives (a cube, an icosphere and an L of two boxes),
so the tests do not depend on the preset shape library.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from fignetctl.core import movi
from fignetctl.core.shapes import ShapeAsset
from fignetctl.core.transforms import (
    quat_angle_deg,
    quat_from_axis_angle,
    quat_to_matrix,
    quat_xyzw_to_wxyz,
    random_quaternions,
    transform_points,
)
from fignetctl.errors import FignetError
from tests.core.stand_in_shapes import stand_in_shapes

GRAVITY = 10.0


@pytest.fixture(scope="module")
def shapes():
    return stand_in_shapes()


def small_config(**overrides):
    settings = dict(duration=1.0, num_objects=(3, 4))
    settings.update(overrides)
    return movi.movi_config("movi-b", **settings)


def simulate(shapes, config, seed, indices, jobs=1):
    return list(movi.generate(shapes, config, seed, indices, jobs=jobs))


# ----------------------------------------------------------------------------- settings


def test_presets_hold_kubric_settings():
    b, c = movi.movi_config("movi-b"), movi.movi_config("movi-c")
    assert (b.physics_hz, b.gravity, b.num_objects) == (240, (0.0, 0.0, -10.0), (3, 10))
    assert b.spawn_region == ((-5.0, -5.0, 1.0), (5.0, 5.0, 5.0))
    assert [(m.friction, m.restitution, m.density) for m in b.materials] == [(0.4, 0.3, 2.7), (0.8, 0.7, 1.1)]
    assert (b.floor_friction, b.floor_restitution, b.scale_range) == (0.3, 0.5, (0.7, 1.4))
    assert c.scale_range == (0.75, 3.0) and c.scale_largest_side
    assert [(m.friction, m.restitution, m.density) for m in c.materials] == [(0.5, 0.5, 1.0)]
    assert json.loads(b.to_json())["materials"][1]["name"] == "rubber"


def test_config_overrides_and_frame_counts():
    config = movi.movi_config("movi-b", fps=60, duration=2.0, num_objects=None)
    assert config.num_objects == (3, 10)
    assert (config.steps_per_frame, config.num_frames) == (4, 121)
    assert config.dt == pytest.approx(1 / 60)


def test_config_json_reads_back_as_the_same_config():
    for config in (movi.movi_config("movi-b", fps=60), movi.movi_config("movi-c", duration=2.0)):
        assert movi.config_from_json(config.to_json()) == config
    for bad in ("{", "[1]", '{"fps": 30, "colour": "red"}'):
        with pytest.raises(FignetError, match="generator config"):
            movi.config_from_json(bad)


@pytest.mark.parametrize("overrides", [dict(fps=25), dict(fps=0), dict(duration=0.0)])
def test_bad_settings_raise_a_user_error(overrides):
    with pytest.raises(FignetError):
        movi.movi_config("movi-b", **overrides)
    with pytest.raises(FignetError, match="unknown preset"):
        movi.movi_config("movi-z")


# ----------------------------------------------------------------------------- mass properties


def test_mass_properties_of_a_cube():
    import trimesh

    cube = trimesh.creation.box((2.0, 2.0, 2.0))
    volume, inertia = movi.mass_properties(cube.vertices, cube.faces, [cube.vertices])
    assert volume == pytest.approx(8.0)
    np.testing.assert_allclose(inertia, np.eye(3) * 8.0 * (4 + 4) / 12, atol=1e-9)


def test_mass_properties_fall_back_to_convex_parts_for_an_open_mesh():
    import trimesh

    cube = trimesh.creation.box((2.0, 2.0, 2.0))
    open_faces = cube.faces[:-2]  # one side missing: no volume
    volume, inertia = movi.mass_properties(cube.vertices, open_faces, [cube.vertices])
    assert volume == pytest.approx(8.0)
    np.testing.assert_allclose(np.diag(inertia), [16 / 3] * 3, rtol=1e-9)


def test_principal_frame_recovers_a_rotated_inertia():
    moments = np.array([1.0, 2.0, 3.5])
    rotation = quat_to_matrix(quat_from_axis_angle([1.0, 2.0, 0.5], 0.7))
    found, quaternion = movi.principal_frame(rotation @ np.diag(moments) @ rotation.T)
    axes = quat_to_matrix(quaternion)
    np.testing.assert_allclose(found, moments, rtol=1e-9)
    np.testing.assert_allclose(
        axes @ np.diag(found) @ axes.T, rotation @ np.diag(moments) @ rotation.T, atol=1e-9
    )


def test_prepared_l_shape_has_its_compound_inertia(tmp_path, shapes):
    ell = movi.prepare_asset(movi.plain_shapes([shapes[2]])[0], tmp_path)
    assert ell.volume == pytest.approx(3.0) and ell.shape.largest_side == pytest.approx(2.0)
    # The L's centre of mass is off both boxes' centres, so its inertia is not diagonal.
    assert abs(ell.inertia[0, 1]) > 0.1
    assert ell.collision_file.endswith(".obj") and Path(ell.collision_file).read_text().count("\no ") == 1


def test_shape_names_must_be_unique_and_not_floor(shapes):
    floor = ShapeAsset("floor", shapes[0].vertices, shapes[0].faces, shapes[0].convex_parts, "test")
    for bad in ([shapes[0], shapes[0]], [floor], []):
        with pytest.raises(FignetError):
            movi.plain_shapes(bad)


# ----------------------------------------------------------------------------- seeds and shards


def test_shards_partition_the_global_indices():
    shards = [set(movi.shard_indices(10, i, 3)) for i in range(3)]
    assert set.union(*shards) == set(range(10)) and sum(map(len, shards)) == 10
    assert list(movi.shard_indices(10, 1, 3)) == [1, 4, 7]
    with pytest.raises(FignetError):
        movi.shard_indices(10, 3, 3)


def test_trajectory_streams_depend_on_seed_index_and_attempt_only():
    draw = lambda *key: movi.trajectory_rng(*key).random(4)
    np.testing.assert_array_equal(draw(1, 5, 0), draw(1, 5, 0))
    assert not np.array_equal(draw(1, 5, 0), draw(1, 6, 0))
    assert not np.array_equal(draw(1, 5, 0), draw(2, 5, 0))
    assert not np.array_equal(draw(1, 5, 0), draw(1, 5, 1))
    assert movi.trajectory_id(7, 100) == "00007" and movi.trajectory_id(7, 1_000_000) == "000007"


# ----------------------------------------------------------------------------- filters


def record(frames=10, objects=2, **arrays):
    """A SimulationRecord of objects resting as unit cubes (lowest vertex at z = 0)."""
    positions = np.zeros((frames, objects, 3))
    positions[:, 1:, 2] = 1.0
    quaternions = np.zeros((frames, objects, 4))
    quaternions[..., 0] = 1.0
    fields = dict(
        positions=positions,
        quaternions=quaternions,
        velocities=np.zeros((frames, objects, 3)),
        angular_velocities=np.zeros((frames, objects, 3)),
        min_pair_distance=np.full(frames, np.inf),
    )
    fields.update(arrays)
    return movi.SimulationRecord(**fields)


def verdict(rec, config=None):
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    objects = rec.positions.shape[1]
    config = config or movi.movi_config("movi-b", fps=30)
    return movi.drop_reason(rec, np.ones(objects), [None] + [cube] * (objects - 1), config)


def test_a_resting_scene_is_kept():
    assert verdict(record()) is None


def test_explosions_are_dropped():
    fast = record()
    fast.velocities[5, 1] = [60.0, 0.0, 0.0]
    spinning = record()
    spinning.angular_velocities[5, 1] = [0.0, 300.0, 0.0]
    far = record()
    far.positions[5, 1] = [150.0, 0.0, 1.0]
    broken = record()
    broken.quaternions[5, 1] = np.nan
    assert [verdict(r) for r in (fast, spinning, far, broken)] == ["explosion"] * 4


def test_tunnelling_is_dropped_but_a_brief_impact_dip_is_not():
    brief = record()
    brief.positions[3, 1, 2] = 1.0 - 0.08  # one frame 8 cm deep, as at a fast impact
    sustained = record()
    sustained.positions[2:7, 1, 2] = 1.0 - 0.06  # 4 frame intervals = 0.13 s at 30 fps
    through = record()
    through.positions[4, 1, 2] = 1.0 - 0.25  # deeper than the floor box
    below = record()
    below.positions[6:, 1, 2] = -0.5
    assert verdict(brief) is None
    assert [verdict(r) for r in (sustained, through, below)] == ["tunnel"] * 3


def test_sustained_interpenetration_is_dropped():
    brief = record(objects=3)
    brief.min_pair_distance[4] = -0.07
    sustained = record(objects=3)
    sustained.min_pair_distance[1:6] = -0.06
    assert verdict(brief) is None and verdict(sustained) == "penetration"


def test_lowest_vertex_heights_match_transformed_vertices():
    rng = np.random.default_rng(0)
    hulls = [rng.normal(size=(20, 3)), rng.normal(size=(7, 3))]
    positions, scales = rng.normal(size=(5, 2, 3)), np.array([0.5, 2.0])
    quaternions = rng.normal(size=(5, 2, 4))
    quaternions /= np.linalg.norm(quaternions, axis=-1, keepdims=True)
    lowest = movi.lowest_vertex_heights(positions, quaternions, scales, hulls)
    for o in range(2):
        expected = transform_points(hulls[o], scales[o], positions[:, o], quaternions[:, o])[..., 2].min(-1)
        np.testing.assert_allclose(lowest[:, o], expected, atol=1e-12)


# ----------------------------------------------------------------------------- simulation


def test_same_seed_gives_identical_trajectories_and_another_seed_does_not(shapes):
    config = small_config()
    first, again, other = (simulate(shapes, config, seed, [0, 1]) for seed in (3, 3, 4))
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.trajectory.positions, b.trajectory.positions)
        np.testing.assert_array_equal(a.trajectory.quaternions, b.trajectory.quaternions)
    assert not np.array_equal(first[0].trajectory.positions[0], other[0].trajectory.positions[0])


def test_shards_and_parallel_jobs_reproduce_the_whole_run(shapes):
    config = small_config(duration=0.5)
    whole = simulate(shapes, config, 9, range(4))
    shard_0 = simulate(shapes, config, 9, movi.shard_indices(4, 0, 2))
    shard_1 = simulate(shapes, config, 9, movi.shard_indices(4, 1, 2), jobs=2)
    assert [r.index for r in shard_1] == [1, 3]
    by_index = {r.index: r for r in shard_0 + shard_1}
    assert sorted(by_index) == [0, 1, 2, 3]
    for result in whole:
        np.testing.assert_array_equal(
            result.trajectory.positions, by_index[result.index].trajectory.positions
        )
        np.testing.assert_array_equal(
            result.trajectory.quaternions, by_index[result.index].trajectory.quaternions
        )


def test_a_crowded_scene_counts_placement_drops_and_gives_up(shapes):
    config = small_config(num_objects=(30, 30), max_placement_trials=5, max_attempts=2, duration=0.1)
    (result,) = simulate(shapes, config, 0, [0])
    assert result.trajectory is None and result.drops == {"placement": 2}
    stats = movi.dataset_stats([result], seconds=1.0, jobs=1)
    assert stats["given_up"] == 1 and stats["dropped"]["placement"] == 2 and stats["attempts"] == 2
    with pytest.raises(FignetError, match="no trajectory"):
        movi.dataset_file([result], shapes, config, 1, {})


def test_trajectory_fields_follow_the_format(shapes, tmp_path):
    from fignetctl.core.trajectory import read_trajectories, write_trajectories

    config = small_config(duration=0.5)
    results = simulate(shapes, config, 2, [0, 1])
    data = movi.dataset_file(results, shapes, config, 2, {"seed": 2})
    back = read_trajectories(write_trajectories(tmp_path / "d.h5", data))
    trajectory = back.trajectories["00000"]
    objects = trajectory.num_objects
    assert trajectory.num_frames == 16 and back.dt == pytest.approx(1 / 30)
    assert trajectory.mesh_names[0] == "floor" and trajectory.static.tolist() == [True] + [False] * (
        objects - 1
    )
    assert trajectory.mass[0] == 0 and np.all(trajectory.mass[1:] > 0)
    assert set(back.meshes) == {"floor"} | {str(n) for t in back.trajectories.values() for n in t.mesh_names}
    np.testing.assert_allclose(back.meshes["floor"].vertices.max(axis=0), [40, 40, 0.1])
    np.testing.assert_allclose(trajectory.positions[:, 0], [[0, 0, -0.1]] * 16, atol=1e-7)
    for name in ("velocities", "angular_velocities"):
        assert getattr(trajectory, name).shape == (16, objects, 3)
    assert trajectory.extras["final_speed"].shape == (objects,)
    assert trajectory.extras["inertia"].shape == (objects, 3, 3)


def test_masses_follow_density_and_scale(shapes):
    config = small_config(duration=0.1)
    (result,) = simulate(shapes, config, 5, [0])
    t = result.trajectory
    volumes = {
        "cube": 8.0,
        "ball": movi.mass_properties(shapes[1].vertices, shapes[1].faces, [])[0],
        "ell": 3.0,
    }
    density = {0.4: 2.7, 0.8: 1.1}  # metal and rubber, told apart by their friction
    objects = zip(t.mesh_names[1:], t.scales[1:], t.friction[1:])
    expected = [density[round(float(f), 1)] * s**3 * volumes[n] for n, s, f in objects]
    np.testing.assert_allclose(t.mass[1:], expected, rtol=1e-5)
    assert np.all((t.scales[1:] >= 0.7) & (t.scales[1:] <= 1.4))


# ----------------------------------------------------------------------------- physical sanity


@pytest.fixture(scope="module")
def tosses(shapes):
    """Two 3 s tosses of cubes, balls and Ls, and two 6 s ones of rubber cubes and Ls.

    Nothing in the last two can roll, and rubber stops sliding sooner: PyBullet multiplies
    the frictions, so metal on the floor has 0.4 × 0.3 = 0.12 and a 12 m/s toss slides ~10 s.
    """
    config = small_config(duration=3.0, num_objects=(4, 6))
    mixed = simulate(shapes, config, 11, [0, 1])
    rubber = dataclasses.replace(config, duration=6.0, materials=(movi.RUBBER,))
    still = simulate([shapes[0], shapes[2]], rubber, 12, [0, 1])
    return config, {s.name: s for s in shapes}, [r.trajectory for r in mixed + still]


def lowest_heights(trajectory, by_name):
    hulls = [by_name[str(n)].vertices for n in trajectory.mesh_names[1:]]
    return movi.lowest_vertex_heights(
        trajectory.positions[:, 1:].astype(float),
        trajectory.quaternions[:, 1:].astype(float),
        trajectory.scales[1:].astype(float),
        hulls,
    )


def energies(trajectory):
    """(T, O) kinetic + potential energy (J) of each object, from the stored fields."""
    rotations = quat_to_matrix(trajectory.quaternions)
    inertia = rotations @ trajectory.extras["inertia"][None] @ np.swapaxes(rotations, -1, -2)
    v, w = trajectory.velocities, trajectory.angular_velocities
    rotational = 0.5 * np.einsum("toi,toij,toj->to", w, inertia, w)
    potential = trajectory.mass * GRAVITY * trajectory.positions[..., 2]
    return 0.5 * trajectory.mass * (v**2).sum(-1) + rotational + potential


def free_flight(trajectory, by_name):
    """(T-1, O) True where an object touches nothing between frames t and t+1.

    Touching nothing: its lowest vertex is 5 cm above the floor and its bounding sphere is
    5 cm from every other object's, at both frames.
    """
    objects = zip(trajectory.mesh_names[1:], trajectory.scales[1:])
    radii = np.array([0.0] + [s * np.linalg.norm(by_name[str(n)].vertices, axis=1).max() for n, s in objects])
    centres = trajectory.positions.astype(float)
    gaps = np.linalg.norm(centres[:, :, None] - centres[:, None], axis=-1) - radii[:, None] - radii[None, :]
    gaps[:, np.arange(len(radii)), np.arange(len(radii))] = np.inf
    gaps[:, 0, :] = gaps[:, :, 0] = np.inf  # the floor is checked through the lowest vertex
    free = np.ones(centres.shape[:2], bool)
    free[:, 1:] = (lowest_heights(trajectory, by_name) > 0.05) & (gaps[:, 1:].min(axis=-1) > 0.05)
    free[:, 0] = False
    return free[:-1] & free[1:]


def test_objects_stay_above_the_floor_and_quaternions_are_unit(tosses):
    _, by_name, trajectories = tosses
    for trajectory in trajectories:
        assert trajectory.positions[:, 1:, 2].min() > 0.0
        assert lowest_heights(trajectory, by_name)[-1].min() > -0.005
        np.testing.assert_allclose(np.linalg.norm(trajectory.quaternions, axis=-1), 1.0, atol=1e-6)


def test_shapes_that_cannot_roll_come_to_rest_on_the_floor(tosses):
    _, by_name, trajectories = tosses
    for trajectory in trajectories[2:]:
        assert trajectory.extras["final_speed"][1:].max() < 0.02
        assert trajectory.extras["final_angular_speed"][1:].max() < 0.05
        lowest = lowest_heights(trajectory, by_name)[-1]
        on_floor = trajectory.positions[-1, 1:, 2] < 1.5  # not resting on another object
        assert on_floor.any() and np.all(np.abs(lowest[on_floor]) < 0.005)


def test_energy_is_conserved_in_free_flight_and_never_grows(tosses):
    _config, by_name, trajectories = tosses
    checked = 0
    for trajectory in trajectories:
        energy = energies(trajectory)
        free = free_flight(trajectory, by_name)
        change = np.abs(np.diff(energy, axis=0))[free]
        # symplectic Euler loses g² h² / 2 per kg per physics step under gravity; allow 1%
        assert np.all(change <= 0.01 * np.abs(energy[:-1][free]) + 0.01)
        checked += free.sum()
        total = energy[:, 1:].sum(axis=1)
        assert total.max() <= total[0] * 1.01
    assert checked > 40  # the check above saw real free flight


def test_angular_momentum_is_conserved_in_free_flight(tosses):
    """Checks the stored quaternions, angular velocities and inertia agree with each other."""
    _, by_name, trajectories = tosses
    checked = 0
    for trajectory in trajectories:
        rotations = quat_to_matrix(trajectory.quaternions)
        inertia = rotations @ trajectory.extras["inertia"][None] @ np.swapaxes(rotations, -1, -2)
        momentum = np.einsum("toij,toj->toi", inertia, trajectory.angular_velocities)
        free = free_flight(trajectory, by_name)
        spinning = np.linalg.norm(momentum[:-1], axis=-1) > 0.5
        for t, o in np.argwhere(free & spinning):
            tolerance = 0.03 * np.linalg.norm(momentum[t, o])
            np.testing.assert_allclose(momentum[t + 1, o], momentum[t, o], rtol=0.0, atol=tolerance)
            checked += 1
    assert checked > 10


def test_a_tumbling_l_keeps_its_angular_momentum_and_energy(tmp_path, shapes):
    """An asymmetric body spun about a slanted axis in zero gravity: checks that PyBullet
    gets the L's full inertia (principal moments in the principal frame) and that the stored
    quaternions are those of the object frame."""
    config = small_config(gravity=(0.0, 0.0, 0.0), duration=2.0)
    spec = movi.ObjectSpec(asset=0, scale=1.0, material=movi.RUBBER)
    with movi.MoviSimulator(movi.plain_shapes([shapes[2]]), config, tmp_path) as simulator:
        ell = simulator.asset(0)
        simulator._reset_world()
        bodies = [simulator._add_floor(), simulator._add_object(spec)]
        simulator.pybullet.resetBasePositionAndOrientation(bodies[1], [0.0, 0.0, 20.0], [0.0, 0.0, 0.0, 1.0])
        simulator.pybullet.resetBaseVelocity(bodies[1], [0.0, 0.0, 0.0], [1.0, 2.0, -0.5])
        record = simulator._run(bodies, [spec])
        grid = np.stack(np.meshgrid(*[np.linspace(-1.2, 1.2, 9)] * 2), -1).reshape(-1, 2)
        probes = record.positions[-1, 1, :2] + grid
        rays = simulator.pybullet.rayTestBatch(
            [[x, y, 30.0] for x, y in probes], [[x, y, 10.0] for x, y in probes]
        )
    world = transform_points(ell.shape.vertices, 1.0, record.positions[-1, 1], record.quaternions[-1, 1])
    expected = top_surface_heights(world, ell.shape.faces, probes)
    hit = np.array([ray[0] >= 0 for ray in rays])
    both = hit & np.isfinite(expected)
    heights = np.array([ray[3][2] for ray in rays])
    # The stored pose puts the mesh where PyBullet's shape is (but for rays grazing an edge).
    assert np.mean(hit == np.isfinite(expected)) > 0.95 and both.sum() > 20
    assert np.quantile(np.abs(heights[both] - expected[both]), 0.9) < 0.003
    rotations = quat_to_matrix(record.quaternions[:, 1])
    inertia = 1.1 * rotations @ ell.inertia @ np.swapaxes(rotations, -1, -2)
    momentum = np.einsum("tij,tj->ti", inertia, record.angular_velocities[:, 1])
    energy = 0.5 * np.einsum("ti,ti->t", record.angular_velocities[:, 1], momentum)
    np.testing.assert_allclose(
        momentum, momentum[:1].repeat(len(momentum), 0), atol=0.02 * np.linalg.norm(momentum[0])
    )
    np.testing.assert_allclose(energy, energy[0], rtol=0.02)
    assert np.ptp(record.angular_velocities[:, 1], axis=0).max() > 0.5  # it does tumble


def test_object_states_read_back_as_set(tmp_path, shapes):
    """set_object_states and object_states convert between object and inertial frames."""
    specs = [movi.ObjectSpec(asset=2, scale=1.3, material=movi.METAL), movi.ObjectSpec(1, 0.8, movi.RUBBER)]
    rng = np.random.default_rng(1)
    positions, velocities, angular = rng.normal(size=(3, 2, 3))
    quaternions = random_quaternions(rng, 2)
    with movi.MoviSimulator(movi.plain_shapes(shapes), small_config(), tmp_path) as simulator:
        bodies = simulator.build_scene(specs)
        simulator.set_object_states(bodies, specs, positions + [0, 0, 5], quaternions, velocities, angular)
        back = simulator.object_states(bodies, specs)
        inertial = simulator.pybullet.getBasePositionAndOrientation(bodies[1])[1]
    np.testing.assert_allclose(back[0], positions + [0, 0, 5], atol=1e-12)
    assert quat_angle_deg(back[1], quaternions).max() < 1e-6
    np.testing.assert_allclose(back[2], velocities, atol=1e-12)
    np.testing.assert_allclose(back[3], angular, atol=1e-12)
    ell = movi.inertial_quaternions(quaternions[0], simulator.asset(2).principal_quaternion)
    assert quat_angle_deg(quat_xyzw_to_wxyz(np.array(inertial)), ell) < 1e-6
    assert quat_angle_deg(ell, quaternions[0]) > 1.0  # the L's principal frame is turned


def top_surface_heights(vertices, faces, points):
    """(Q,) the highest z where a vertical line through each (x, y) meets the mesh (-inf: none).

    vertices : (V, 3), faces : (F, 3), points : (Q, 2)
    """
    a, b, c = (vertices[faces[:, k]] for k in range(3))  # (F, 3) each
    e1, e2 = (b - a)[:, :2], (c - a)[:, :2]
    determinant = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    d = points[:, None, :] - a[None, :, :2]  # (Q, F, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (d[..., 0] * e2[:, 1] - d[..., 1] * e2[:, 0]) / determinant
        v = (e1[:, 0] * d[..., 1] - e1[:, 1] * d[..., 0]) / determinant
    inside = (u >= 0) & (v >= 0) & (u + v <= 1) & (np.abs(determinant) > 1e-12)
    z = a[:, 2] + u * (b - a)[:, 2] + v * (c - a)[:, 2]
    return np.where(inside, z, -np.inf).max(axis=1)
