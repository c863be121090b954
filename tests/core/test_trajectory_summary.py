import numpy as np
import pytest

from fignetctl.core.trajectory_summary import angular_velocities, energies, lowest_vertex_heights, summarize
from tests.conftest import box_drop_file


def test_free_fall_with_spin_conserves_energy():
    data = box_drop_file(frames=30, spin=4.0, height=5.0)
    trajectory = data.trajectories["00000"]
    energy = energies(data, trajectory)
    assert energy["kinetic_rotational"].min() > 0.1  # the box really spins
    total = energy["total"]
    assert np.ptp(total) < 1e-3 * np.abs(total).max()


def test_constant_spin_is_measured_exactly():
    data = box_drop_file(frames=8, spin=4.0)
    omega = angular_velocities(data.trajectories["00000"].quaternions, data.dt)
    np.testing.assert_allclose(np.linalg.norm(omega[:, 1], axis=1), 4.0, rtol=1e-4)
    np.testing.assert_allclose(omega[:, 0], 0.0)


def test_summary_counts_and_lowest_vertex():
    data = box_drop_file(frames=5, spin=0.0, height=2.0)
    summary = summarize(data)
    assert (summary["trajectories"], summary["frames"], summary["objects"]) == (1, 5, 2)
    lowest = lowest_vertex_heights(data, data.trajectories["00000"])
    assert lowest[0] == pytest.approx(1.5)  # a unit box centred at 2 m


def _spinning_cuboid_file(frames=6, dt=1 / 30, spin=5.0, extents=(2.0, 1.0, 0.5), scale=1.5, mass=3.0):
    """A cuboid in free flight (gravity off) spinning at `spin` rad/s about its own x axis,
    from a tilted start orientation."""
    import dataclasses

    import trimesh

    from fignetctl.core.trajectory import Mesh
    from fignetctl.core.transforms import quat_from_axis_angle, quat_multiply

    base = box_drop_file(frames=frames, dt=dt, spin=0.0)
    start = quat_from_axis_angle(np.array([0.3, -0.5, 0.8]), 1.1)
    body_spin = quat_from_axis_angle(np.array([1.0, 0.0, 0.0])[None], spin * np.arange(frames) * dt)
    trajectory = base.trajectories["00000"]
    trajectory.quaternions[:, 1] = quat_multiply(start, body_spin)
    trajectory.positions[:, 1] = [0.0, 0.0, 3.0] + np.arange(frames)[:, None] * dt * np.array([1.0, 2.0, 0.0])
    trajectory.scales[1], trajectory.mass[1] = scale, mass
    cuboid = trimesh.creation.box(extents=extents)
    base.meshes["box"] = Mesh(np.asarray(cuboid.vertices, np.float32), np.asarray(cuboid.faces, np.int32))
    return dataclasses.replace(base, gravity=np.zeros(3))


def test_spinning_cuboid_in_free_flight_has_the_analytic_rotational_energy():
    data = _spinning_cuboid_file()
    energy = energies(data, data.trajectories["00000"])
    b, c = 1.0 * 1.5, 0.5 * 1.5
    inertia_about_x = 3.0 * (b**2 + c**2) / 12.0
    np.testing.assert_allclose(energy["kinetic_rotational"], 0.5 * inertia_about_x * 5.0**2, rtol=1e-4)
    np.testing.assert_allclose(energy["kinetic_translational"], 0.5 * 3.0 * 5.0, rtol=1e-4)  # |v|² = 1 + 4
    np.testing.assert_allclose(energy["potential"], 0.0)


def test_mesh_inertia_matches_trimesh_with_the_same_mass():
    import trimesh

    from fignetctl.core.trajectory_summary import mesh_inertia

    mesh = trimesh.creation.cone(radius=0.7, height=1.3)
    mesh.apply_translation(-mesh.center_mass)
    scaled = mesh.copy()
    scaled.apply_scale(2.0)
    scaled.density = 5.0 / scaled.volume
    expected = scaled.moment_inertia
    np.testing.assert_allclose(
        mesh_inertia(mesh.vertices, mesh.faces, 2.0, 5.0), expected, rtol=1e-9, atol=1e-12
    )
    inside_out = mesh_inertia(mesh.vertices, mesh.faces[:, ::-1], 2.0, 5.0)
    np.testing.assert_allclose(inside_out, expected, rtol=1e-9, atol=1e-12)


def test_flat_mesh_inertia_is_finite():
    from fignetctl.core.trajectory_summary import mesh_inertia

    square = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    inertia = mesh_inertia(square, np.array([[0, 1, 2], [0, 2, 3]]), 1.0, 2.0)
    assert np.all(np.isfinite(inertia)) and inertia[2, 2] == pytest.approx(
        4.0
    )  # 4 point masses of ½ kg at √2 m


def test_world_vertices_follow_the_pose_and_give_the_lowest_height():
    from fignetctl.core.trajectory_summary import world_vertices

    data = box_drop_file(frames=4, spin=3.0)
    trajectory = data.trajectories["00000"]
    lowest = lowest_vertex_heights(data, trajectory)
    for frame in range(4):
        floor, box = world_vertices(data, "00000", frame)
        np.testing.assert_allclose(floor, data.meshes["floor"].vertices, atol=1e-6)
        np.testing.assert_allclose(box.mean(axis=0), trajectory.positions[frame, 1], atol=1e-5)
        assert box[:, 2].min() == pytest.approx(lowest[frame], abs=1e-5)


def test_summary_is_json_ready_and_the_text_lists_every_object():
    import json

    from fignetctl.core.trajectory_summary import format_summary

    summary = summarize(box_drop_file(frames=6, height=1.5))
    trajectory = json.loads(json.dumps(summary))["per_trajectory"][0]
    assert len(trajectory["energy"]["total"]) == len(trajectory["lowest_vertex_z"]) == 6
    assert [row["mesh"] for row in trajectory["object_table"]] == ["floor", "box"]
    assert trajectory["max_speed"] == pytest.approx(10.0 * 5 / 60, rel=1e-3)  # g·t after 5 frames at 60 fps
    text = format_summary(summary)
    assert "trajectory 00000: 6 frames" in text and "floor" in text and "box" in text


@pytest.mark.parametrize("frames", [1, 2])
def test_one_or_two_frames_give_finite_numbers(frames):
    summary = summarize(box_drop_file(frames=frames))
    energy = summary["per_trajectory"][0]["energy"]
    assert all(np.isfinite(energy[key]).all() for key in energy)
