"""Physics ceilings: what PyBullet reaches when restarted every frame from a model's inputs.

A learned simulator predicts frame t+1 from what it is given at frame t. Restarting PyBullet
from the same information shows what physics itself allows with it:

- `finite-difference`: each dynamic body is put at its rolled-out pose of frame t with the
  velocity estimated from the rolled-out poses of frames t-1 and t ((p_t − p_{t−1}) / dt, and
  the rotation vector of q_t ⊗ q_{t−1}⁻¹ / dt, world frame);
- `velocity`: at its rolled-out pose of frame t with the rolled-out instantaneous velocity
  (PyBullet's after the frame's last physics step; at the first step, the file's frame 1).

Each restart is a fresh PyBullet world built as make-dataset built the trajectory's scene (same
shapes by name, scales, materials, floor and engine settings, from the file's `config`
attribute), so no solver state outlives a frame: only the state above carries over. With
keep_world=True the bodies are instead reset in one world kept for the whole rollout, so
PyBullet's contact manifolds (the contact points it accumulates over steps) carry over too:
not a restart from the model's information, but a reference for how much they matter. One
frame is physics_hz / fps physics steps. Rollouts start from frames 0 and 1 of the ground
truth; rollout frame 1 + k is step k, as in the model's rollouts.

`evaluate_nudged` asks how chaotic the scenes are: PyBullet runs freely (no restarts) in one
world from frame 1's recorded pose and velocity, with every dynamic object first moved by a
nudge of a few millimetres or less in a random direction. A simulator whose state is off by
that much at one frame typically ends about this far off later, however well it knows the
physics; with no nudge it shows how closely PyBullet replays its own recording from the
stored (float32) state.
"""

from __future__ import annotations

import tempfile

import numpy as np

from fignetctl.core import movi
from fignetctl.core.model.evaluation import PAPER_STEPS, rotation_errors_deg, translation_errors
from fignetctl.core.trajectory import TrajectoryFile, estimated_velocities
from fignetctl.errors import FignetError

STATES = ("finite-difference", "velocity")
SECONDS_HORIZONS = (0.1, 0.2, 0.33, 0.5, 1.0, 1.67)
MASS_RTOL = 1e-4  # stored masses are float32; a larger mismatch means another asset or material


# ----------------------------------------------------------------------------- the scene


def generator_config(data: TrajectoryFile) -> movi.MoviSettings:
    """The MoviSettings in the file's `config` attribute (make-dataset writes it), checked against
    the file's frame time; FignetError for a file without it."""
    if "config" not in data.attrs:
        raise FignetError(
            "this trajectory file was not made by `fignetctl make-dataset` (no generator config)"
        )
    config = movi.config_from_json(data.attrs["config"])
    if not np.isclose(config.dt, data.dt, rtol=1e-9) or not np.allclose(config.gravity, data.gravity):
        raise FignetError(
            f"the file's dt {data.dt:g} s or gravity is not its generator config's ({config.dt:g} s)"
        )
    return config


def generator_assets(data: TrajectoryFile, config: movi.MoviSettings) -> list:
    """The preset's ShapeAssets of every mesh the file's trajectories use (the floor aside)."""
    from fignetctl.core.shapes import load_shapes

    names = sorted({str(n) for t in data.trajectories.values() for n in t.mesh_names} - {movi.FLOOR_NAME})
    return load_shapes(config.preset, "all", names=names)


def check_assets_match_file(assets, data: TrajectoryFile) -> None:
    """FignetError unless each asset's mesh is the file's mesh of that name (same vertices)."""
    for asset in assets:
        mesh = data.meshes.get(str(asset.name))
        vertices = np.asarray(asset.vertices, np.float32)
        if mesh is not None and (
            mesh.vertices.shape != vertices.shape or not np.array_equal(mesh.vertices, vertices)
        ):
            raise FignetError(
                f"shape {asset.name!r} is not the one that made this file (has its recipe changed?)"
            )


def object_specs(trajectory, config: movi.MoviSettings, asset_index: dict, simulator) -> list:
    """One ObjectSpec per dynamic object (objects 1..O-1), checked against the stored masses.

    asset_index : mesh name -> index into the simulator's shapes
    """
    check_floor(trajectory, config)
    specs = []
    for o in range(1, trajectory.num_objects):
        material = stored_material(config, trajectory.friction[o], trajectory.restitution[o])
        spec = movi.ObjectSpec(
            asset_index[str(trajectory.mesh_names[o])], float(trajectory.scales[o]), material
        )
        mass, _ = movi.object_mass_properties(simulator.asset(spec.asset), spec)
        if not np.isclose(mass, trajectory.mass[o], rtol=MASS_RTOL, atol=0.0):
            raise FignetError(
                f"object {o} weighs {trajectory.mass[o]:.6g} kg in the file but {mass:.6g} kg rebuilt"
            )
        specs.append(spec)
    return specs


def check_floor(trajectory, config: movi.MoviSettings) -> None:
    """FignetError unless object 0 is the config's floor and every other object is dynamic."""
    layout = [True] + [False] * (trajectory.num_objects - 1)
    if str(trajectory.mesh_names[0]) != movi.FLOOR_NAME or trajectory.static.tolist() != layout:
        raise FignetError(
            "a make-dataset trajectory has the floor as object 0 and only dynamic objects after it"
        )
    floor = (np.float32(config.floor_friction), np.float32(config.floor_restitution))
    if (trajectory.friction[0], trajectory.restitution[0]) != floor:
        raise FignetError("the floor's friction and restitution are not the generator config's")


def stored_material(config: movi.MoviSettings, friction, restitution) -> movi.Material:
    """The config's material with this (float32-stored) friction and restitution."""
    stored = (np.float32(friction), np.float32(restitution))
    for material in config.materials:
        if (np.float32(material.friction), np.float32(material.restitution)) == stored:
            return material
    raise FignetError(
        f"no material of the generator config has friction {friction:g} and restitution {restitution:g}"
    )


# ----------------------------------------------------------------------------- restarts


def finite_difference_velocities(positions, quaternions, dt):
    """Velocities at the later of two frames from their poses, world frame.

    positions : (2, N, 3), quaternions : (2, N, 4) w x y z, frames t-1 and t
    returns : linear (N, 3) m/s, angular (N, 3) rad/s, float64
    """
    linear, angular = estimated_velocities(positions, quaternions, dt)
    return linear[1], angular[1]


def restarted_frame(
    simulator, bodies, specs, positions, quaternions, velocities, angular_velocities
) -> tuple:
    """One frame of PyBullet with the dynamic objects put in the given state.

    bodies : the scene's body ids, the floor first (MoviSimulator.build_scene)
    positions (N, 3), quaternions (N, 4) w x y z, velocities, angular_velocities (N, 3)
    returns : the state one frame later, the same four arrays, float64
    """
    simulator.set_object_states(bodies, specs, positions, quaternions, velocities, angular_velocities)
    simulator.step_frame()
    return simulator.object_states(bodies, specs)


def restarted_rollout(simulator, specs, trajectory, state: str, num_steps: int, dt: float, keep_world=False):
    """Poses of the dynamic objects (objects 1..O-1) restarted every frame from `state`, each
    frame in a fresh world (keep_world=False) or in one world kept throughout.

    returns : positions (2 + K, N, 3), quaternions (2 + K, N, 4) float64; frames 0-1 the truth's
    """
    positions = [np.asarray(trajectory.positions[f, 1:], np.float64) for f in (0, 1)]
    quaternions = [np.asarray(trajectory.quaternions[f, 1:], np.float64) for f in (0, 1)]
    if state == "velocity":
        velocities = [
            np.asarray(v[1, 1:], np.float64) for v in (trajectory.velocities, trajectory.angular_velocities)
        ]
    kept = simulator.build_scene(specs) if keep_world else None
    for _ in range(num_steps):
        bodies = kept if keep_world else simulator.build_scene(specs)
        if state == "finite-difference":
            velocities = finite_difference_velocities(
                np.stack(positions[-2:]), np.stack(quaternions[-2:]), dt
            )
        pose_and_velocities = (positions[-1], quaternions[-1], *velocities)
        position, quaternion, *velocities = restarted_frame(simulator, bodies, specs, *pose_and_velocities)
        positions.append(position)
        quaternions.append(quaternion)
    return np.stack(positions), np.stack(quaternions)


def nudged_rollout(simulator, specs, trajectory, num_steps: int, nudge: float, rng):
    """Poses of the dynamic objects (objects 1..O-1) run freely for `num_steps` frames in one
    world from frame 1's recorded pose and velocity, each object's position first moved by
    `nudge` metres in a direction drawn from `rng`.

    returns : positions (2 + K, N, 3), quaternions (2 + K, N, 4) float64; frames 0-1 the truth's
    (frame 1 as recorded, before the nudge)
    """
    positions = [np.asarray(trajectory.positions[f, 1:], np.float64) for f in (0, 1)]
    quaternions = [np.asarray(trajectory.quaternions[f, 1:], np.float64) for f in (0, 1)]
    directions = rng.normal(size=positions[1].shape)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    velocities = [
        np.asarray(v[1, 1:], np.float64) for v in (trajectory.velocities, trajectory.angular_velocities)
    ]
    bodies = simulator.build_scene(specs)
    simulator.set_object_states(
        bodies, specs, positions[1] + float(nudge) * directions, quaternions[1], *velocities
    )
    for _ in range(num_steps):
        simulator.step_frame()
        position, quaternion, _, _ = simulator.object_states(bodies, specs)
        positions.append(position)
        quaternions.append(quaternion)
    return np.stack(positions), np.stack(quaternions)


class RestartedPyBullet:
    """PyBullet set up as make-dataset was for one trajectory file; rolls its scenes out restarted.

    data : a TrajectoryFile written by make-dataset
    assets : ShapeAsset-like objects (name, vertices, faces, convex_parts) of the file's shapes;
        default: the generator preset's shapes of those names (checked against the file's meshes)
    keep_world : reset the bodies in one world per rollout instead of a fresh world per frame
    Use as a context manager, or call close().
    """

    def __init__(self, data: TrajectoryFile, assets=None, keep_world: bool = False):
        self.data, self.keep_world = data, bool(keep_world)
        self.config = generator_config(data)
        assets = generator_assets(data, self.config) if assets is None else list(assets)
        check_assets_match_file(assets, data)
        self.asset_index = {str(asset.name): index for index, asset in enumerate(assets)}
        self._folder = tempfile.TemporaryDirectory(prefix="fignetctl-ceilings-")
        self.simulator = movi.MoviSimulator(movi.plain_shapes(assets), self.config, self._folder.name)

    def rollout(self, trajectory_id: str, state: str, num_steps: int) -> tuple:
        """The restarted rollout of one trajectory, all objects (static ones keep frame 1's pose).

        returns : positions (2 + K, O, 3), quaternions (2 + K, O, 4) w x y z, float64
        """
        trajectory = self._trajectory(trajectory_id, state)
        specs = object_specs(trajectory, self.config, self.asset_index, self.simulator)
        moving = restarted_rollout(
            self.simulator, specs, trajectory, state, int(num_steps), self.data.dt, self.keep_world
        )
        return self._with_static(trajectory, moving, int(num_steps))

    def nudged(self, trajectory_id: str, num_steps: int, nudge: float, seed: int = 0) -> tuple:
        """The free run of one trajectory from frame 1 nudged by `nudge` metres (nudged_rollout),
        all objects (static ones keep frame 1's pose); the directions follow from `seed`.

        returns : positions (2 + K, O, 3), quaternions (2 + K, O, 4) w x y z, float64
        """
        if not nudge >= 0.0:
            raise FignetError(f"the nudge must be a distance >= 0 m, got {nudge}")
        trajectory = self._trajectory(trajectory_id, "velocity")
        specs = object_specs(trajectory, self.config, self.asset_index, self.simulator)
        rng = np.random.default_rng([int(seed), list(self.data.trajectories).index(trajectory_id)])
        moving = nudged_rollout(self.simulator, specs, trajectory, int(num_steps), nudge, rng)
        return self._with_static(trajectory, moving, int(num_steps))

    def frame(self, trajectory_id: str, positions, quaternions, velocities, angular_velocities) -> tuple:
        """One frame of PyBullet in a fresh world of the trajectory's scene, its dynamic objects
        put in the given state (restarted_frame); the floor stays where make-dataset put it.

        positions (O, 3), quaternions (O, 4) w x y z, velocities, angular_velocities (O, 3) m/s
            and rad/s, every object (the static rows are not read)
        returns the four arrays one frame later, float64, static rows as given
        """
        trajectory = self._trajectory(trajectory_id, "finite-difference")
        specs = object_specs(trajectory, self.config, self.asset_index, self.simulator)
        given = [
            np.array(values, np.float64)
            for values in (positions, quaternions, velocities, angular_velocities)
        ]
        bodies = self.simulator.build_scene(specs)
        after = restarted_frame(self.simulator, bodies, specs, *(values[1:] for values in given))
        for values, moved in zip(given, after):
            values[1:] = moved
        return tuple(given)

    def _with_static(self, trajectory, moving, num_steps: int) -> tuple:
        """The dynamic objects' rolled-out poses with the static ones at frame 1's (frames 0-1
        the truth's)."""
        positions = np.repeat(trajectory.positions[1:2].astype(np.float64), 2 + num_steps, axis=0)
        quaternions = np.repeat(trajectory.quaternions[1:2].astype(np.float64), 2 + num_steps, axis=0)
        positions[:2], quaternions[:2] = trajectory.positions[:2], trajectory.quaternions[:2]
        positions[:, 1:], quaternions[:, 1:] = moving
        return positions, quaternions

    def _trajectory(self, trajectory_id: str, state: str):
        if state not in STATES:
            raise FignetError(f"unknown state {state!r}; choose one of {', '.join(STATES)}")
        if trajectory_id not in self.data.trajectories:
            raise FignetError(f"no trajectory {trajectory_id!r} in the file")
        trajectory = self.data.trajectories[trajectory_id]
        if trajectory.num_frames < 2:
            raise FignetError(
                f"trajectory {trajectory_id!r} has fewer than the 2 frames a rollout starts from"
            )
        if state == "velocity" and not trajectory.has_velocities:
            raise FignetError(
                "the 'velocity' state needs recorded velocities; this file has none (format version 1)"
            )
        missing = sorted({str(n) for n in trajectory.mesh_names[1:]} - set(self.asset_index))
        if missing:
            raise FignetError(f"no asset given for the shapes {', '.join(missing)}")
        return trajectory

    def close(self) -> None:
        self.simulator.close()
        self._folder.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def ceiling_rollout(
    data: TrajectoryFile, trajectory_id: str, state: str, num_steps: int, assets=None, keep_world=False
) -> tuple:
    """The restarted-PyBullet rollout of one trajectory (see the module docstring).

    returns : positions (2 + K, O, 3), quaternions (2 + K, O, 4) w x y z, float64; frames 0
        and 1 the ground truth's, static objects at their given poses
    """
    with RestartedPyBullet(data, assets, keep_world) as physics:
        return physics.rollout(trajectory_id, state, num_steps)


# ----------------------------------------------------------------------------- evaluation


def horizon_steps(dt: float, num_frames: int, seconds=SECONDS_HORIZONS, steps=(PAPER_STEPS,)) -> list:
    """Sorted distinct horizons in rollout steps: `steps` and round(t / dt) for t in `seconds`,
    leaving out those a trajectory of num_frames frames is too short for (step k is frame 1 + k)."""
    candidates = {int(s) for s in steps} | {int(round(t / dt)) for t in seconds}
    return sorted(h for h in candidates if 1 <= h <= num_frames - 2)


def horizon_errors(positions, quaternions, trajectory, steps: int) -> tuple:
    """Per dynamic object, the translation (m) and rotation (degrees) error at a horizon.

    positions (2 + K, O, 3), quaternions (2 + K, O, 4): a rollout of `trajectory`
    returns : (N,), (N,) float64 over the dynamic objects
    """
    dynamic, frame = ~np.asarray(trajectory.static), 1 + steps
    translation = translation_errors(positions[frame, dynamic], trajectory.positions[frame, dynamic])
    rotation = rotation_errors_deg(quaternions[frame, dynamic], trajectory.quaternions[frame, dynamic])
    return translation, rotation


def error_summary(translation, rotation) -> dict:
    """translation, rotation : (N,) errors of N objects -> RMSE (m), mean and RMS angle (deg)."""
    translation, rotation = np.asarray(translation, np.float64), np.asarray(rotation, np.float64)
    return {
        "translation_rmse_m": float(np.sqrt(np.mean(translation**2))),
        "rotation_mean_deg": float(np.mean(rotation)),
        "rotation_rms_deg": float(np.sqrt(np.mean(rotation**2))),
        "objects": int(translation.size),
    }


def evaluate_ceilings(
    data: TrajectoryFile, horizons=None, num_trajectories=None, states=STATES, assets=None, keep_world=False
) -> dict:
    """Both ceilings over the first `num_trajectories` trajectories of a make-dataset file.

    horizons : rollout steps (default: horizon_steps of the shortest trajectory evaluated)
    returns : {"trajectories", "objects", "dt", "horizons", "keep_world", "states": {state: [one
        dict per horizon: steps, seconds, translation_rmse_m, rotation_mean_deg, rotation_rms_deg,
        objects]}}
    """
    ids, horizons = _trajectories_and_horizons(data, num_trajectories, horizons)
    with RestartedPyBullet(data, assets, keep_world) as physics:
        errors = {
            state: collect_errors(
                physics, ids, horizons, lambda key, steps, state=state: physics.rollout(key, state, steps)
            )
            for state in states
        }
    return {
        **_run_summary(data, ids, horizons),
        "keep_world": bool(keep_world),
        "states": {state: [horizon_row(h, data.dt, *errors[state][h]) for h in horizons] for state in states},
    }


def evaluate_nudged(
    data: TrajectoryFile, horizons=None, num_trajectories=None, nudges=(0.0, 1e-4, 1e-3), seed=0, assets=None
) -> dict:
    """The free runs of `nudged_rollout` over the first `num_trajectories` trajectories, one per
    nudge (metres), against the recording.

    returns : {"trajectories", "objects", "dt", "horizons", "seed", "nudges": {"<nudge> m": [one
        dict per horizon: steps, seconds, translation_rmse_m, rotation_mean_deg, rotation_rms_deg,
        objects]}}
    """
    ids, horizons = _trajectories_and_horizons(data, num_trajectories, horizons)
    rows = {}
    with RestartedPyBullet(data, assets) as physics:
        for nudge in nudges:
            errors = collect_errors(
                physics,
                ids,
                horizons,
                lambda key, steps, nudge=nudge: physics.nudged(key, steps, nudge, seed),
            )
            rows[f"{nudge:g} m"] = [horizon_row(h, data.dt, *errors[h]) for h in horizons]
    return {
        **_run_summary(data, ids, horizons),
        "seed": int(seed),
        "nudges": rows,
    }


def _run_summary(data: TrajectoryFile, ids, horizons) -> dict:
    """What every evaluation here reports first: the trajectories, their dynamic objects, dt and
    the horizons."""
    return {
        "trajectories": len(ids),
        "objects": int(sum((~data.trajectories[key].static).sum() for key in ids)),
        "dt": float(data.dt),
        "horizons": horizons,
    }


def _trajectories_and_horizons(data: TrajectoryFile, num_trajectories, horizons) -> tuple:
    """The first `num_trajectories` trajectory ids and the sorted horizons (default:
    horizon_steps of the shortest of them), or a clear error."""
    ids = list(data.trajectories)[:num_trajectories]
    if not ids:
        raise FignetError("no trajectories to evaluate")
    shortest = min(data.trajectories[key].num_frames for key in ids)
    horizons = horizon_steps(data.dt, shortest) if horizons is None else sorted({int(h) for h in horizons})
    if not horizons or horizons[0] < 1 or horizons[-1] > shortest - 2:
        raise FignetError(
            f"horizons must lie in 1..{shortest - 2} steps for these trajectories, got {horizons}"
        )
    return ids, horizons


def collect_errors(physics: RestartedPyBullet, ids, horizons, run) -> dict:
    """horizon -> (translation errors (N,), rotation errors (N,)) over the dynamic objects of
    the trajectories `ids`, each rolled out once to the longest horizon by `run(id, steps)`."""
    errors = {h: ([], []) for h in horizons}
    for key in ids:
        positions, quaternions = run(key, horizons[-1])
        for h in horizons:
            translation, rotation = horizon_errors(positions, quaternions, physics.data.trajectories[key], h)
            errors[h][0].append(translation)
            errors[h][1].append(rotation)
    return {h: (np.concatenate(t), np.concatenate(r)) for h, (t, r) in errors.items()}


def horizon_row(steps: int, dt: float, translation, rotation) -> dict:
    """One horizon's row: steps, seconds and `error_summary` of the objects' errors there."""
    return {"steps": steps, "seconds": round(steps * dt, 4), **error_summary(translation, rotation)}
