"""A model applied to trajectories: loading it, rolling a scene out, evaluating it on ground truth
(arrays in, arrays out; the rollout and evaluate stages read and write the files)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging

import numpy as np

from fignetctl.core.model.checkpoint import BUNDLED, DEFAULT_BUNDLED, bundled_model_path, load_checkpoint
from fignetctl.core.model.rollout import RolloutError, guards_for, rollout
from fignetctl.core.model.scene_data import (
    EVALUATION_STATIC_REACH,
    MIN_FACES,
    mesh_settings,
    scene_from_trajectory,
)
from fignetctl.core.model.trained_ranges import outside_ranges
from fignetctl.core.trajectory import TrajectoryFile
from fignetctl.errors import FignetError, SettingError

log = logging.getLogger(__name__)


def load_model(path=None, device="cpu", rotations=None, max_faces=None):
    """A model file, a bundled checkpoint by name, or the bundled FIGNet* when `path` is None.

    rotations : the turns about gravity its network is averaged over, instead of the file's.
    max_faces : each moving object's mesh decimated to at most this many faces instead of the
        file's (0: whole meshes); the network is the same, the scenes it reads are finer or coarser.
    """
    if path is None or path in BUNDLED:
        path = bundled_model_path(path or DEFAULT_BUNDLED)
        if not path.is_file():
            raise FignetError(f"no bundled model at {path}; pass a `model` file (from `fignetctl train`)")
    simulator = load_checkpoint(path, device=device)
    if rotations is not None:
        simulator.rotations = rotations
    if max_faces is not None:
        if 0 < max_faces < MIN_FACES:
            raise SettingError(
                f"max_faces = {max_faces}: give 0 (whole meshes) or at least {MIN_FACES} faces"
            )
        simulator.config = dataclasses.replace(simulator.config, max_faces_per_object=max_faces or None)
    return simulator


def simulation_time_step(simulator, data, key, where) -> float:
    """Seconds per step of a rollout of trajectory `key` of a file.

    A velocity-state model steps at the time step it was trained at, whatever the scene's
    frame time: it starts from frame 1's pose and velocity, and frame 0 is not read (unless
    static objects move: their given frames must then be at that time step). A positions-state
    model reads frames 0 and 1 as one of its steps, so they must be its time step apart.
    Models that record no time step take the file's.
    """
    trained = simulator.config.dt
    if trained is None or np.isclose(trained, data.dt, rtol=1e-3):
        return data.dt if trained is None else trained
    trajectory = data.trajectories[key]
    static = np.asarray(trajectory.static, bool)
    still = np.allclose(trajectory.positions[:, static], trajectory.positions[:1, static]) and np.allclose(
        trajectory.quaternions[:, static], trajectory.quaternions[:1, static]
    )
    if simulator.config.uses_velocities and still:
        return trained
    raise FignetError(
        f"{where}: its frames are {data.dt:.6g} s apart, the model steps {trained:.6g} s "
        f"({'static objects move over the given frames' if simulator.config.uses_velocities else 'its two input frames must be one step apart'}); "
        f"give the scene at dt = {trained:.6g} s"
    )


def rollout_trajectory(
    simulator,
    data: TrajectoryFile,
    num_steps,
    on_step=None,
    sim_scale=1.0,
    sleep=False,
    free_flight=False,
    keep_out=False,
    where="scene",
) -> TrajectoryFile:
    """Roll out the first trajectory of `data` (`where` names it in messages); a RolloutError
    carries the frames before it as `partial_file` too.

    sim_scale : simulate the scene scaled by this factor (or "auto": froude.auto_scale with
        the model's trained_properties) and map the frames back; the result's frame time is then dt / √sim_scale
        (fignetctl.core.model.froude)
    sleep : let resting objects sleep (fignetctl.core.model.rollout.SleepSettings)
    free_flight : objects that touch nothing fly exactly (LearnedSimulator.step)
    keep_out : objects are moved back out of static meshes they pass into (penetration.py)

    A scene under another gravity g' than the model's g is simulated under g in the time that
    makes it the same motion (froude; gravity pointing elsewhere, or none, is refused). The
    result holds the model's time step (`simulation_time_step`) over √(sim_scale · g'/g), and
    the velocities of a velocity-state model.
    """
    from fignetctl.core.model import froude

    key = next(iter(data.trajectories))
    if data.trajectories[key].num_frames < 2:
        raise FignetError(f"{where}: trajectory {key!r} has 1 frame; a rollout needs 2 (t-1 and t)")
    step_dt = simulation_time_step(simulator, data, key, where)
    trained = getattr(simulator, "trained_properties", None)
    scale = froude.auto_scale(data, key, trained) if sim_scale == "auto" else float(sim_scale)
    ratio = froude.gravity_ratio(data.gravity, simulator.config.gravity, where)
    mapped = scale != 1.0 or ratio != 1.0
    simulated = data
    if mapped:
        simulated, history = froude.scaled_scene(data, key, scale, ratio)
    scene = scene_from_trajectory(simulated, key, simulator.config)
    warn_untrained_properties(simulator, [data.trajectories[key]])
    guards = guards_for(step_dt, simulated.gravity, sleep, free_flight, keep_out)

    def result(frames):
        if mapped:
            frames = froude.unscaled_frames(frames, history, scale, ratio)
        return rollout_result(
            data, key, *frames, simulator, step_dt / froude.time_factor(scale, ratio), scale, ratio
        )

    try:
        frames = rollout(simulator, scene, num_steps, on_step, guards=guards, with_velocities=True)
    except RolloutError as error:
        error.partial_file = result((error.positions, error.quaternions, None, None))
        raise
    return result(frames)


def warn_untrained_properties(simulator, trajectories) -> None:
    """Log a warning, once each, for every property of the trajectories' objects that the model
    never saw."""
    ranges, found = getattr(simulator, "trained_properties", None), {}
    for trajectory in trajectories:
        for sentence in outside_ranges(
            ranges, trajectory.mesh_names, trajectory.static, trajectory.properties
        ):
            found.setdefault(sentence)
    for sentence in found:
        log.warning(
            "%s: the rollout extrapolates (see the active and passive properties of build-graph)", sentence
        )


def rollout_result(
    data,
    key,
    positions,
    quaternions,
    velocities,
    angular_velocities,
    simulator,
    dt=None,
    sim_scale=1.0,
    gravity_ratio=1.0,
) -> TrajectoryFile:
    """A trajectory file of the rollout: the scene's meshes and objects, the new frames (with
    velocities when given, (T, O, 3) m/s and rad/s); its attrs say at which scale and under
    which gravity (the scene's over the model's) it was simulated."""
    trajectory = dataclasses.replace(
        data.trajectories[key],
        positions=positions.astype(np.float32),
        quaternions=(quaternions / np.linalg.norm(quaternions, axis=-1, keepdims=True)).astype(np.float32),
        velocities=None if velocities is None else velocities.astype(np.float32),
        angular_velocities=None if velocities is None else angular_velocities.astype(np.float32),
        extras={},
    )
    used = set(trajectory.mesh_names)
    meshes = {name: mesh for name, mesh in data.meshes.items() if name in used}
    attrs = {
        "source": "fignetctl rollout",
        "model_config": simulator.config.to_json(),
        "sim_scale": float(sim_scale),
        "gravity_ratio": float(gravity_ratio),
        "rotations": simulator.rotations,
    }
    return TrajectoryFile(data.dt if dt is None else dt, data.gravity, meshes, {key: trajectory}, attrs)


def evaluate_trajectories(
    simulator,
    data: TrajectoryFile,
    max_trajectories=None,
    on_scene=None,
    sleep=False,
    free_flight=False,
    keep_out=False,
    with_guards=False,
    ceilings=False,
    where="data",
    against=None,
) -> dict:
    """Metrics (evaluation.evaluate_scenes) of a model on the trajectories of `data` (`where`
    names it in messages);
    `with_guards` also evaluates it as `rollout` runs it (free flight, keep-out, sleeping);
    `ceilings` also evaluates PyBullet restarted every frame from each state (core/ceilings.py;
    the file must come from make-dataset); `against`, another simulator, is rolled out on the
    same trajectories with the same guards as method "against", so that the comparison holds
    the model against it, trajectory by trajectory."""
    from fignetctl.core.model.evaluation import evaluate_scenes

    keys = list(data.trajectories)[:max_trajectories]
    for model in (simulator,) if against is None else (simulator, against):
        check_comparable(model, data, where)
    warn_untrained_properties(simulator, [data.trajectories[key] for key in keys])
    scenes = _scenes_of(data, keys, simulator.config)
    guards = guards_for(data.dt, data.gravity, sleep, free_flight, keep_out)
    guarded = guards_for(data.dt, data.gravity, True, True, True) if with_guards else None
    with contextlib.ExitStack() as stack:
        references = physics_ceilings(data, stack) if ceilings else {}
        if against is not None:
            alike = mesh_settings(against.config) == mesh_settings(simulator.config)
            against_scenes = scenes if alike else _scenes_of(data, keys, against.config)
            references["against"] = functools.partial(_model_rollout, against, against_scenes, guards)
        results = evaluate_scenes(
            simulator, data, list(scenes.values()), on_scene, guards, guarded, references
        )
    if not results:
        raise FignetError(f"{where}: no trajectory is long enough for a 50-step or 2-second horizon")
    return {
        "dt": data.dt,
        "trajectories": len(scenes),
        "sleep": bool(sleep),
        "free_flight": bool(free_flight),
        "keep_out": bool(keep_out),
        "ceilings": bool(ceilings),
        "rotations": simulator.rotations,
        "max_faces": simulator.config.max_faces_per_object,
        **results,
    }


def check_comparable(simulator, data, where) -> None:
    """Refuse a model whose time step or gravity differ from the file's."""
    from fignetctl.core.model import froude

    if simulator.config.dt is not None and not np.isclose(simulator.config.dt, data.dt, rtol=1e-3):
        raise FignetError(
            f"{where}: its frames are {data.dt:.6g} s apart, the model steps {simulator.config.dt:.6g} s, "
            "so its rollouts cannot be compared with them frame by frame; evaluate on data at the model's time step"
        )
    if froude.gravity_ratio(data.gravity, simulator.config.gravity, where) != 1.0:
        raise FignetError(
            f"{where}: its gravity is {np.linalg.norm(data.gravity):.4g} m/s², the model learned "
            f"{np.linalg.norm(simulator.config.gravity):.4g} m/s², so its rollouts cannot be compared with them "
            "frame by frame; evaluate on data under the model's gravity (`rollout` maps a scene to it)"
        )


def _scenes_of(data, keys, config) -> dict:
    """name -> Scene of each trajectory as a model of `config` reads it (its meshes' faces)."""
    cache = {}
    return {key: scene_from_trajectory(data, key, config, cache, EVALUATION_STATIC_REACH) for key in keys}


def _model_rollout(simulator, scenes, guards, scene, num_steps):
    return rollout(simulator, scenes[scene.name], num_steps, guards=guards)


def physics_ceilings(data, stack: contextlib.ExitStack) -> dict:
    """{ceiling_velocity, ceiling_finite_difference: function(scene, num_steps) -> rollout} from
    PyBullet rebuilt for a make-dataset file, closed with `stack`; the velocity ceiling only
    when the file records velocities."""
    from fignetctl.core.ceilings import RestartedPyBullet

    physics = stack.enter_context(RestartedPyBullet(data))
    states = ["velocity"] if any(t.has_velocities for t in data.trajectories.values()) else []
    return {
        f"ceiling_{state.replace('-', '_')}": functools.partial(_ceiling_rollout, physics, state)
        for state in states + ["finite-difference"]
    }


def _ceiling_rollout(physics, state, scene, num_steps):
    return physics.rollout(scene.name, state, num_steps)
