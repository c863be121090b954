"""Where a velocity-state model's next vertex positions come from, at rollout time.

A velocity-state network answers two things per vertex: a_x, which places it at
x_{t+1} = x_t + u_t + a_x, and a_u, which gives its next velocity u_{t+1} = u_t + a_u. The two
are trained apart, so the positions could come from either:

- `position`: a_x, as the model is trained and as every command runs it;
- `velocity`: the trapezoid rule on the velocities, x_{t+1} = x_t + (u_t + u_{t+1}) / 2, that is
  a_x = a_u / 2 (exact in free fall; it undershoots a turn of θ per step by about θ² / 6);
- `mean`: halfway between the two.

The velocities are the network's a_u in every case. This runs a benchmark script, or
`fignetctl` itself, with the positions taken from SOURCE:

    python benchmarks/position_source.py velocity fignetctl evaluate data/movi-b-test.h5 \
        --rotations 4 -o eval-velocity.json
    python benchmarks/position_source.py velocity benchmarks/long_rollout.py \
        --model fignet-star-movi-b --data data/movi-b-test.h5 -n 10 --steps 120 --rotations 4 \
        --out long-velocity.json

and, with `recorded` for SOURCE, how much of the recorded a_x the trapezoid rule on the recorded
velocities leaves unexplained (FVU over all dynamic vertices and steps of the first N
trajectories of a make-dataset file, whose velocities are the instantaneous ones):

    python benchmarks/position_source.py recorded data/movi-b-test.h5 40
"""

import contextlib
import json
import runpy
import sys

import numpy as np

import fignetctl.core.model.simulator as simulator_module

SOURCES = ("position", "velocity", "mean")


def position_step(acceleration, source):
    """The (n, 6) network acceleration [a_x, a_u] with a_x taken from `source`."""
    acceleration = np.array(acceleration, np.float64)
    if source not in SOURCES:
        raise ValueError(f"source {source!r}: choose one of {', '.join(SOURCES)}")
    trapezoid = acceleration[:, 3:] / 2
    if source == "velocity":
        acceleration[:, :3] = trapezoid
    elif source == "mean":
        acceleration[:, :3] = (acceleration[:, :3] + trapezoid) / 2
    return acceleration


@contextlib.contextmanager
def positions_from(source):
    """Within the block, LearnedSimulator steps (simulator.integrate) place vertices from
    `source`, applied to the whole step (a free-motion model's computed part included)."""
    original = simulator_module.integrate

    def integrate(acceleration, vertices_previous, vertices_now, free_motion=None):
        if np.shape(acceleration)[1] != 6:
            return original(acceleration, vertices_previous, vertices_now, free_motion)
        total = acceleration if free_motion is None else np.asarray(acceleration) + free_motion
        return original(position_step(total, source), vertices_previous, vertices_now)

    simulator_module.integrate = integrate
    try:
        yield
    finally:
        simulator_module.integrate = original


def trapezoid_residuals(vertices, vertex_velocities):
    """vertices (T, n, 3) and their velocities per step (T, n, 3), frames 0..T−1 ->
    the recorded a_x = x_{t+1} − x_t − u_t and what the trapezoid rule leaves of it,
    a_x − a_u / 2, for t = 0..T−2, each (T − 1, n, 3)."""
    vertices, vertex_velocities = np.asarray(vertices, np.float64), np.asarray(vertex_velocities, np.float64)
    a_x = vertices[1:] - vertices[:-1] - vertex_velocities[:-1]
    a_u = vertex_velocities[1:] - vertex_velocities[:-1]
    return a_x, a_x - a_u / 2


def recorded_fvu(path, count):
    """{fvu, vertex_steps}: the trapezoid rule's share of the recorded a_x's variance left
    unexplained, over every dynamic vertex and step of the first `count` trajectories."""
    from fignetctl.core.model.scene_data import scene_from_trajectory
    from fignetctl.core.model.scene_graph import rigid_point_velocities
    from fignetctl.core.model.simulator import SimulatorConfig
    from fignetctl.core.trajectory import read_trajectories

    data = read_trajectories(path)
    targets, residuals = [], []
    for key in list(data.trajectories)[:count]:
        scene = scene_from_trajectory(data, key, SimulatorConfig())
        if not scene.velocities_recorded:
            raise SystemExit(f"{path}: trajectory {key} records no velocities (make-dataset files do)")
        dynamic = scene.geometry.dynamic_vertices
        owner = scene.geometry.vertex_object[dynamic]
        vertices = np.stack(
            [scene.geometry.world_vertices(p, q, dynamic) for p, q in zip(scene.positions, scene.quaternions)]
        )
        velocities = np.stack(
            [
                rigid_point_velocities(x, owner, c, v, w)
                for x, c, v, w in zip(vertices, scene.positions, scene.velocities, scene.angular_velocities)
            ]
        )
        a_x, residual = trapezoid_residuals(vertices, velocities * data.dt)
        targets.append(a_x.reshape(-1, 3))
        residuals.append(residual.reshape(-1, 3))
    targets, residuals = np.concatenate(targets), np.concatenate(residuals)
    variance = np.sum((targets - targets.mean(axis=0)) ** 2)
    return {"fvu": float(np.sum(residuals**2) / variance), "vertex_steps": len(targets)}


def main(argv):
    if len(argv) == 3 and argv[0] == "recorded":
        print(json.dumps(recorded_fvu(argv[1], int(argv[2]))))
        return
    if len(argv) < 2 or argv[0] not in SOURCES:
        sys.exit(
            f"usage: position_source.py {{{','.join(SOURCES)}}} (fignetctl | SCRIPT.py) ARGS...\n"
            "       position_source.py recorded DATA N"
        )
    source, command, arguments = argv[0], argv[1], argv[2:]
    with positions_from(source):
        sys.argv = [command, *arguments]
        if command == "fignetctl":
            from fignetctl.cli import main as fignetctl

            fignetctl()
        else:
            runpy.run_path(command, run_name="__main__")


if __name__ == "__main__":
    main(sys.argv[1:])
