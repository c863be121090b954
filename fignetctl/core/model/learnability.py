"""How much of the one-step targets a model explains: the learnability measure.

A simulator that cannot fit the frames it was trained on cannot roll them out either. The
fraction of the target variance left unexplained,

    FVU = Σ (prediction − target)² / Σ (target − mean target)²

over every dynamic vertex of every frame t of the given scenes (no training noise), with the
targets and predictions in the model's normalized units, is 1 for a model that predicts the
mean and 0 for a perfect one. benchmarks/learnability.py overfits two movi-b trajectories and
reports it, with `bar`'s verdict; the suite asserts it on seconds-long cases.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from fignetctl.core.model.graph import batch_graphs

FVU_BAR = 0.10
"""The issue's bar on the one-step fit of the training frames: FVU at most 10 %."""
TRACKING_TOLERANCE_M = 0.10
"""A rollout of training trajectories tracks them when, at each horizon, its translation RMSE is
within this of PyBullet's restarted every frame from the same state on the same trajectories
(what physics itself drifts there); 0.1 m is about a twentieth of a movi-b object's largest side."""


CUBE_CASES = {
    "dropped": (1, 0, ((-0.5, -0.5, 1.0), (0.5, 0.5, 2.0))),  # falls, bounces, slides, comes to rest
    "tossed": (2, 3, ((-1.5, -1.5, 0.6), (1.5, 1.5, 1.5))),  # two tossed at each other, collide at frame 12
}
"""The seconds-long learnability cases: (cubes, seed, spawn region) of `cube_trajectories`."""


def cube_asset():
    """A unit cube as a generator shape (its own single convex part)."""
    import trimesh

    from fignetctl.core.shapes import ShapeAsset

    box = trimesh.creation.box((1.0, 1.0, 1.0))
    vertices = np.asarray(box.vertices, np.float32)
    return ShapeAsset(
        name="cube",
        vertices=vertices,
        faces=np.asarray(box.faces, np.int32),
        convex_parts=(vertices,),
        source="fignetctl.core.model.learnability",
    )


def cube_trajectories(count, seed, spawn_region):
    """One 1 s trajectory of `count` rubber unit cubes tossed in `spawn_region` (make-dataset's
    generator: PyBullet, MOVi-B's settings, 30 fps), as a TrajectoryFile that carries its
    generator config as make-dataset's files do (so `ceilings` can run it again)."""
    from fignetctl.core import movi

    asset = cube_asset()
    config = movi.movi_config(
        "movi-b",
        duration=1.0,
        num_objects=(count, count),
        spawn_region=spawn_region,
        materials=(movi.RUBBER,),
        scale_range=(1.0, 1.0),
    )
    results = list(movi.generate([asset], config, seed, range(1)))
    attrs = {"source": "fignetctl.core.model.learnability.cube_trajectories", "config": config.to_json()}
    return movi.dataset_file(results, [asset], config, 1, attrs)


def one_step_examples(simulator, scenes, frames_per_scene=None, seed=0):
    """Noise-free (graph, targets) of frames t of the scenes: all frames with t−1 and t+1
    inside the trajectory, or `frames_per_scene` drawn from them."""
    from fignetctl.core.model.training import TrainingSettings, training_example

    clean = TrainingSettings(noise_translation_std=0.0, noise_rotation_std=0.0)
    rng = np.random.default_rng(seed)
    generator = torch.Generator().manual_seed(seed)
    examples = []
    for scene in scenes:
        frames = np.arange(1, scene.positions.shape[0] - 1)
        if frames_per_scene is not None and frames_per_scene < len(frames):
            frames = np.sort(rng.choice(frames, frames_per_scene, replace=False))
        examples += [
            training_example(simulator.config, scene, int(frame), generator, clean) for frame in frames
        ]
    return examples


@torch.no_grad()
def fraction_unexplained(simulator, examples, batch_size=16) -> dict:
    """{"all": FVU over every component, "position": over a_x, "velocity": over a_u (velocity
    state only), "per_component": [...]} of a model on one_step_examples (averaged over its
    `rotations`). For a `free_motion` model these are of what its network must output, the
    change from free motion, a smaller target than the whole correction: compare models of both
    kinds by `rigid_fraction_unexplained`."""
    from fignetctl.core.model.training import dynamic_rows

    predictions, targets = [], []
    for start in range(0, len(examples), batch_size):
        chunk = examples[start : start + batch_size]
        graph = batch_graphs([scene_graph.graph for scene_graph, _ in chunk])
        rows = dynamic_rows([scene_graph for scene_graph, _ in chunk])
        predictions.append(simulator.normalized_targets(simulator.network_acceleration(graph), False)[rows])
        targets.append(simulator.normalized_targets(torch.cat([t for _, t in chunk]), accumulate=False))
    prediction, target = torch.cat(predictions).double(), torch.cat(targets).double()
    residual = ((prediction - target) ** 2).sum(0)
    spread = ((target - target.mean(0)) ** 2).sum(0)
    result = {
        "all": float(residual.sum() / spread.sum()),
        "position": float(residual[:3].sum() / spread[:3].sum()),
        "per_component": (residual / spread.clamp(min=1e-300)).tolist(),
        "vertices": int(target.shape[0]),
    }
    if target.shape[1] == 6:
        result["velocity"] = float(residual[3:].sum() / spread[3:].sum())
    return result


@torch.no_grad()
def rigid_corrections(simulator, scenes):
    """For each noise-free frame t of the scenes, (scene, t, predicted, recorded): the (Vd, 3), or
    (Vd, 6) for a velocity state, per-vertex corrections a_x = x_{t+1} − x_t − u_t (and
    a_u = u_{t+1} − u_t) of the next pose (and velocity) that `simulator.predict` (the network
    alone, shape matching and the rigid velocity fit included) steps to, and of the recorded one."""
    for scene, t, step, truth in one_steps(simulator, scenes):
        yield scene, t, _vertex_corrections(scene, t, step), _vertex_corrections(scene, t, truth)


def one_steps(simulator, scenes):
    """For each noise-free frame t of the scenes, (scene, t, predicted, recorded): the next
    (positions, quaternions, linear and angular velocities in m/s and rad/s, or None, None for a
    positions state) that `simulator.predict` (the network alone) steps to from the recorded
    frame t, and the recorded ones."""
    for scene in scenes:
        for t in range(1, scene.positions.shape[0] - 1):
            velocities = None
            if simulator.config.uses_velocities:
                velocities = (scene.velocities[t], scene.angular_velocities[t])
            step = simulator.predict(
                scene.geometry,
                scene.positions[t - 1 : t + 2],
                scene.quaternions[t - 1 : t + 2],
                velocities=velocities,
            )
            truth = (scene.positions[t + 1], scene.quaternions[t + 1], None, None)
            if velocities is not None:
                truth = truth[:2] + (scene.velocities[t + 1], scene.angular_velocities[t + 1])
            yield scene, t, step, truth


def rigid_fraction_unexplained(simulator, scenes) -> dict:
    """FVU of the rigid next step, what a rollout keeps, whatever the network decodes: the
    `rigid_corrections` of the predicted and the recorded next pose (and velocity), compared
    per component over every dynamic vertex.

    {"all": mean over the components of their FVU, "position": over a_x's three, "velocity":
    over a_u's three (velocity state only), "per_component": [...]}"""
    predicted, recorded = [], []
    for _, _, prediction, truth in rigid_corrections(simulator, scenes):
        predicted.append(prediction)
        recorded.append(truth)
    prediction, target = np.concatenate(predicted), np.concatenate(recorded)
    per_component = ((prediction - target) ** 2).sum(0) / ((target - target.mean(0)) ** 2).sum(0)
    result = {
        "all": float(per_component.mean()),
        "position": float(per_component[:3].mean()),
        "per_component": per_component.tolist(),
    }
    if len(per_component) == 6:
        result["velocity"] = float(per_component[3:].mean())
    return result


def regime_errors(simulator, scenes, radii=()) -> dict:
    """The `rigid_corrections` errors of a model split by the regime the recording has each
    vertex's object in over the step (`training.object_regimes`), in millimetres per frame:
    {regime: {"share": of the vertex-frames, "target_rms_mm" and "error_rms_mm": {"position":
    of |a_x|, "velocity": of |a_u| (velocity state)}, "bias_mm":
    the mean error of the last correction (a_u, else a_x) upwards (negative: it pulls
    down), "error_share": of the squared error over all regimes}}. Small errors on calm objects
    are what a rollout adds up frame after frame; on impacts they are what the loss is made of.

    With `radii` (m), each regime also gets "out_of_reach": {radius: {"share": of the regime's
    vertex-frames whose object has no face within that radius of another object's face at
    frame t (`objects_out_of_reach`: no face–face edge at that collision radius), "error_share":
    theirs of the squared error over all regimes}}: how much of the error a larger radius
    could give the network something to work with.

    A velocity-state model's regimes also get "response": {"share": of the dynamic
    object-frames, "linear" and "angular": `step_response` of the change over the step of each
    object's velocity beyond free fall's (m/s) and of its spin (rad/s)}, how much of what the
    recording's step changes the network's step changes."""
    from fignetctl.core.model.training import REGIMES, object_regimes

    gravity = np.asarray(simulator.config.gravity, np.float64)
    down = gravity / np.linalg.norm(gravity)
    velocity_state = simulator.config.uses_velocities
    labels, errors, targets, out_of_reach = [], [], [], []
    object_labels, changes = [], {"linear": ([], []), "angular": ([], [])}
    for scene, t, step, recorded in one_steps(simulator, scenes):
        prediction, truth = _vertex_corrections(scene, t, step), _vertex_corrections(scene, t, recorded)
        owner = scene.geometry.vertex_object[scene.geometry.dynamic_vertices]
        regimes = object_regimes(scene, t, gravity, velocity_state)
        labels.append(regimes[owner])
        errors.append(prediction - truth)
        targets.append(truth)
        out_of_reach.append(objects_out_of_reach(scene, t, radii)[:, owner])
        if velocity_state:
            dynamic = ~scene.geometry.static
            object_labels.append(regimes[dynamic])
            for part, column, now, fall in (
                ("linear", 2, scene.velocities[t], gravity * scene.dt),
                ("angular", 3, scene.angular_velocities[t], 0.0),
            ):
                changes[part][0].append((step[column] - now - fall)[dynamic])
                changes[part][1].append((recorded[column] - now - fall)[dynamic])
    label, error, target = np.concatenate(labels), np.concatenate(errors), np.concatenate(targets)
    out_of_reach = np.concatenate(out_of_reach, axis=1)
    squared = (error**2).sum(1)
    total = float(squared.sum())
    parts = (
        {"position": slice(0, 3), "velocity": slice(3, 6)} if velocity_state else {"position": slice(0, 3)}
    )
    last = parts["velocity" if velocity_state else "position"]

    def rms(values, rows):
        return float(np.sqrt((values[rows] ** 2).sum(1).mean()) * 1e3)

    result = {}
    for index, name in enumerate(REGIMES):
        rows = label == index
        if not rows.any():
            result[name] = {"share": 0.0}
            continue

        result[name] = {
            "share": float(rows.mean()),
            "target_rms_mm": {part: rms(target[:, cut], rows) for part, cut in parts.items()},
            "error_rms_mm": {part: rms(error[:, cut], rows) for part, cut in parts.items()},
            "bias_mm": float((error[rows, last] @ -down).mean() * 1e3),
            "error_share": float(squared[rows].sum() / total) if total else 0.0,
        }
        if velocity_state:
            objects = np.concatenate(object_labels) == index
            result[name]["response"] = {
                "share": float(objects.mean()),
                **{
                    part: step_response(np.concatenate(predicted)[objects], np.concatenate(truth)[objects])
                    for part, (predicted, truth) in changes.items()
                },
            }
        if len(radii):
            result[name]["out_of_reach"] = {
                f"{radius:g}": {
                    "share": float(far[rows].mean()),
                    "error_share": float(squared[rows & far].sum() / total) if total else 0.0,
                }
                for radius, far in zip(radii, out_of_reach)
            }
    return result


RESPONSE_RESOLUTION = 1e-3
"""m/s or rad/s: recorded changes over a step whose RMS is under this have no `captured` slope."""


def step_response(predicted, recorded) -> dict:
    """How much of the recorded changes (N, 3) a model's predicted ones follow: {"target_rms" and
    "error_rms": RMS of |recorded| and of |predicted − recorded|, "captured": the least-squares
    slope of predicted on recorded through zero, Σ p·r / Σ |r|² (1: the whole change, 0: none;
    below 1, the network answers with a shrunken change, as a least-squares fit does with what
    it cannot tell apart), None when the recorded changes' RMS is under RESPONSE_RESOLUTION, as
    in free fall, where the recording's linear change beyond free fall is float rounding}."""
    if not len(recorded):
        return {"target_rms": 0.0, "error_rms": 0.0, "captured": None}
    target_rms = float(np.sqrt((recorded**2).sum(1).mean()))
    return {
        "target_rms": target_rms,
        "error_rms": float(np.sqrt(((predicted - recorded) ** 2).sum(1).mean())),
        "captured": float((predicted * recorded).sum() / (recorded**2).sum())
        if target_rms >= RESPONSE_RESOLUTION
        else None,
    }


def objects_out_of_reach(scene, t, radii) -> np.ndarray:
    """(len(radii), O) bool: whether each object of `scene` has no face within each radius (m)
    of a face of another object at frame t, so a graph of that collision radius gives it no
    face–face edge (static pairs never pair, as in the graph)."""
    from fignetctl.core.model.scene_graph import collision_face_pairs

    geometry = scene.geometry
    far = np.ones((len(radii), geometry.num_objects), bool)
    vertices = geometry.world_vertices(scene.positions[t], scene.quaternions[t]) if len(radii) else None
    for row, radius in enumerate(radii):
        i, j = collision_face_pairs(geometry, vertices, radius)
        far[row, geometry.face_object[i]] = False
        far[row, geometry.face_object[j]] = False
    return far


def _vertex_corrections(scene, t, after):
    """(Vd, 3) a_x, or (Vd, 6) [a_x, a_u], of the dynamic vertices going from frame t of `scene`
    to `after` = (positions, quaternions, linear, angular velocities in m/s and rad/s, or None):
    u_t is the recorded velocity of frame t when `after` has velocities, else x_t − x_{t−1}."""
    from fignetctl.core.model.scene_graph import rigid_point_velocities

    geometry, dt = scene.geometry, scene.dt
    rows = geometry.dynamic_vertices
    owner = geometry.vertex_object[rows]
    now = geometry.world_vertices(scene.positions[t], scene.quaternions[t], rows)
    if after[2] is None:
        u_now = now - geometry.world_vertices(scene.positions[t - 1], scene.quaternions[t - 1], rows)
        return geometry.world_vertices(after[0], after[1], rows) - now - u_now
    u_now = rigid_point_velocities(
        now, owner, scene.positions[t], scene.velocities[t] * dt, scene.angular_velocities[t] * dt
    )
    next_vertices = geometry.world_vertices(after[0], after[1], rows)
    u_next = rigid_point_velocities(next_vertices, owner, after[0], after[2] * dt, after[3] * dt)
    return np.concatenate([next_vertices - now - u_now, u_next - u_now], axis=1)


def overfit(
    simulator_config,
    scenes,
    steps,
    batch_size=4,
    learning_rate=(1e-3, 1e-4),
    loss="mse",
    precision="fp32",
    seed=0,
    until_step=None,
    noise=(0.0, 0.0),
    frame_sampling="uniform",
    gravity=(0.0, 0.0, -10.0),
    **settings,
):
    """A Trainer that has fitted `scenes` for `steps`, or for `until_step` of a `steps`-long
    schedule (continue it with `trainer.run(until_step=...)`); without noise (the learnability
    test) unless `noise` gives training's per-object jitter (translation m, rotation rad);
    `gravity` (m/s²) is the scenes' (for `frame_sampling` 'motion'); `settings`: other
    TrainingSettings fields (`pushforward`, `calm_weight`, ...)."""
    from fignetctl.core.model.simulator import LearnedSimulator
    from fignetctl.core.model.training import Trainer, TrainingSettings

    config = TrainingSettings(
        steps=steps,
        batch_size=batch_size,
        learning_rate_initial=learning_rate[0],
        learning_rate_final=learning_rate[1],
        noise_translation_std=noise[0],
        noise_rotation_std=noise[1],
        loss=loss,
        precision=precision,
        normalizer_accumulation_steps=min(200, steps),
        checkpoint_every=10**9,
        seed=seed,
        frame_sampling=frame_sampling,
        **settings,
    )
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        simulator = LearnedSimulator(
            dataclasses.replace(simulator_config, dt=scenes[0].dt, gravity=tuple(gravity))
        )
    trainer = Trainer(scenes, simulator, config)
    trainer.run(until_step=until_step)
    return trainer


def bar(fvu: float, rollout_rmse: dict, ceiling_rmse: dict) -> dict:
    """The learnability bar: FVU ≤ FVU_BAR and, at every horizon of `ceiling_rmse`,
    a rollout translation RMSE ≤ the ceiling's + TRACKING_TOLERANCE_M.

    rollout_rmse, ceiling_rmse : {steps: translation RMSE (m)} of the model's rollout of its
        training trajectories and of PyBullet restarted from the same state on them
    returns : {"fvu": {value, at_most, met}, "tracks": [{steps, model_m, ceiling_m, at_most_m,
        met}], "met"}
    """
    if not ceiling_rmse or set(ceiling_rmse) - set(rollout_rmse):
        raise ValueError(
            f"rollout horizons {sorted(rollout_rmse)} must cover the ceiling's {sorted(ceiling_rmse)}"
        )
    fit = {"value": float(fvu), "at_most": FVU_BAR, "met": bool(fvu <= FVU_BAR)}
    tracks = []
    for steps in sorted(ceiling_rmse):
        at_most = float(ceiling_rmse[steps]) + TRACKING_TOLERANCE_M
        model = float(rollout_rmse[steps])
        tracks.append(
            {
                "steps": int(steps),
                "model_m": model,
                "ceiling_m": float(ceiling_rmse[steps]),
                "at_most_m": at_most,
                "met": bool(model <= at_most),
            }
        )
    return {"fvu": fit, "tracks": tracks, "met": fit["met"] and all(row["met"] for row in tracks)}
