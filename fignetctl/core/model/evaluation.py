"""The paper's metrics for rollouts against ground truth, and two baselines to compare with.

Translation error: RMSE over dynamic objects of |p_pred − p_gt| at a horizon (metres).
Rotation error: mean over dynamic objects of the angle of q_gt⁻¹ · q_pred (degrees), and its
RMS beside it. Horizons: 50 rollout steps (the paper's count, at the data's frame rate) and
physical times 0.1, 0.2, 0.33, 0.5, 1.0, 1.67 and 2 s (so results at different frame rates,
the paper's included, compare only at a matched time); a trajectory too short for a horizon is
left out of that horizon.

Each horizon's errors are also given per shape and per motion (`per_motion`): what the
recording does with the object over the horizon (`object_motions`: only free flight and rest,
or contact, or an impact), with each class's share of the squared translation error.

Beside the metrics: the same errors at every rollout step (`curves`), and the model against
each baseline on the same objects (`comparison`): the ratio of translation RMSEs and the
difference of mean rotation errors, each with a 95 % bootstrap interval over trajectories
(resampled together for both methods), and the share of objects the model places closer.

Baselines (what learning buys):
- `stand_still`: every object keeps its pose of frame 1;
- `constant_velocity`: every object keeps its last velocity and spin, gains gravity, and stops
  when its lowest vertex reaches the floor height (the lowest static vertex) — no contact,
  friction or bounce.

References (what physics allows), when given: any rollouts made outside the model, such as the
PyBullet ceilings of fignetctl/core/ceilings.py (`ceiling_velocity`,
`ceiling_finite_difference`), measured and compared like the baselines.
"""

from __future__ import annotations

import numpy as np

from fignetctl.core.transforms import quat_angle_deg

PAPER_STEPS = 50
SECONDS_HORIZONS = (0.1, 0.2, 0.33, 0.5, 1.0, 1.67, 2.0)
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 0
MOTIONS = ("calm", "contact", "impact")
"""`object_motions`' classes, each the worst step of the horizon: calm (every step free fall, or
at rest or moving steadily), contact (some step changes its motion, none by an impact's), impact."""


def translation_errors(predicted, truth):
    """(O, 3) x2 -> (O,) distances."""
    return np.linalg.norm(np.asarray(predicted, np.float64) - np.asarray(truth, np.float64), axis=1)


def rotation_errors_deg(predicted, truth):
    """(O, 4) x2 -> (O,) angles of q_gt⁻¹ q_pred in degrees."""
    return quat_angle_deg(np.asarray(truth, np.float64), np.asarray(predicted, np.float64))


def stand_still_baseline(scene, num_steps):
    """Poses (2 + K, O, ·): frames 0, 1, then frame 1 repeated."""
    positions = np.concatenate([scene.positions[:2], np.repeat(scene.positions[1:2], num_steps, 0)])
    quaternions = np.concatenate([scene.quaternions[:2], np.repeat(scene.quaternions[1:2], num_steps, 0)])
    return positions, quaternions


def constant_velocity_baseline(scene, num_steps, gravity, dt):
    """Free flight (simulator.free_flight_poses) from frames 0–1 that stops at the floor;
    poses (2 + K, O, ·)."""
    from fignetctl.core.model.simulator import free_flight_poses

    geometry = scene.geometry
    floor = _floor_height(geometry, scene.positions[1], scene.quaternions[1])
    positions, quaternions = (
        [scene.positions[0], scene.positions[1]],
        [scene.quaternions[0], scene.quaternions[1]],
    )
    moving = ~geometry.static.copy()
    step_gravity = np.asarray(gravity, np.float64) * dt * dt
    for _ in range(num_steps):
        flown = free_flight_poses(positions[-2:], quaternions[-2:], step_gravity)
        position = np.where(moving[:, None], flown[0], positions[-1])
        quaternion = np.where(moving[:, None], flown[1], quaternions[-1])
        landed = moving & (lowest_object_z(geometry, position, quaternion) <= floor)
        position[landed] = positions[-1][landed]
        quaternion[landed] = quaternions[-1][landed]
        moving &= ~landed
        positions.append(position)
        quaternions.append(quaternion)
    return np.stack(positions), np.stack(quaternions)


def lowest_object_z(geometry, positions, quaternions):
    """(O,) lowest world z of each object's vertices."""
    z = geometry.world_vertices(positions, quaternions)[:, 2]
    lowest = np.full(geometry.num_objects, np.inf)
    np.minimum.at(lowest, geometry.vertex_object, z)
    return lowest


def _floor_height(geometry, positions, quaternions):
    """The lowest static vertex, or −inf when the scene has no static object."""
    lowest = lowest_object_z(geometry, positions, quaternions)
    return lowest[geometry.static].min() if geometry.static.any() else -np.inf


def horizon_steps(dt, num_frames):
    """{'50_steps': 50, '0.1_seconds': k, ...} for the horizons a trajectory of num_frames
    covers (a time is round(time / dt) steps, at least one)."""
    horizons = {f"{PAPER_STEPS}_steps": PAPER_STEPS}
    horizons.update(
        {f"{seconds:g}_seconds": max(1, int(round(seconds / dt))) for seconds in SECONDS_HORIZONS}
    )
    return {name: steps for name, steps in horizons.items() if 1 + steps < num_frames}


def errors_at(scene, positions, quaternions, step):
    """Per dynamic object at rollout step `step` (frame 1 + step): translation m, rotation deg."""
    dynamic = ~scene.geometry.static
    frame = 1 + step
    translation = translation_errors(positions[frame][dynamic], scene.positions[frame][dynamic])
    rotation = rotation_errors_deg(quaternions[frame][dynamic], scene.quaternions[frame][dynamic])
    return translation, rotation


def object_motions(scene, horizons, gravity) -> dict:
    """{horizon: (D,) the `MOTIONS` class of each dynamic object of `scene`} for `horizons`
    ({name: steps}) of a rollout from frame 1: the worst of the recording's steps t -> t + 1,
    t = 1 … steps, as training.object_regimes classes them (an impact: a change of motion beyond
    gravity's of more than training.IMPACT |g| dt² per frame; calm: free fall or no change,
    within training.CALM_TOLERANCE); from the recorded velocities, or those estimated from the
    poses. The steps are classed once, up to the longest horizon."""
    from fignetctl.core.model.training import REGIMES, object_regimes

    if not horizons:
        return {}
    dynamic = ~scene.geometry.static
    steps = range(1, max(horizons.values()) + 1)
    regimes = np.array([object_regimes(scene, t, gravity)[dynamic] for t in steps])
    calm = np.isin(regimes, [REGIMES.index("free fall"), REGIMES.index("at rest or steady")])
    calm_so_far = np.logical_and.accumulate(calm, axis=0)  # [k]: calm over steps 1 … k + 1
    impact_so_far = np.logical_or.accumulate(regimes == REGIMES.index("impact"), axis=0)
    motions = {}
    for horizon, count in horizons.items():
        motion = np.where(calm_so_far[count - 1], 0, 1)
        motion[impact_so_far[count - 1]] = 2
        motions[horizon] = np.asarray(MOTIONS)[motion]
    return motions


def summarize_errors(records):
    """records: dicts with 'translation' and 'rotation' arrays -> RMSE (m) and mean angle (deg)."""
    if not records:
        return None
    translation = np.concatenate([r["translation"] for r in records])
    rotation = np.concatenate([r["rotation"] for r in records])
    return {
        "translation_rmse_m": float(np.sqrt(np.mean(translation**2))),
        "rotation_error_deg": float(np.mean(rotation)),
        "rotation_rms_deg": float(np.sqrt(np.mean(rotation**2))),
        "objects": int(translation.size),
        "trajectories": len(records),
    }


def method_rollouts(simulator, scene, num_steps, gravity, dt, guards=None, guarded=None, references=None):
    """name -> (positions, quaternions) for the model (with rollout.Guards `guards`, None: the
    network alone), the model with the Guards `guarded` (None: not run), both baselines and each
    reference: {name: function(scene, num_steps) -> (positions, quaternions)}, frames 0..1+num_steps."""
    from fignetctl.core.model.rollout import Guards, rollout

    rollouts = {"model": rollout(simulator, scene, num_steps, guards=guards or Guards())}
    if guarded is not None:
        rollouts["model_with_guards"] = rollout(simulator, scene, num_steps, guards=guarded)
    rollouts["constant_velocity"] = constant_velocity_baseline(scene, num_steps, gravity, dt)
    rollouts["stand_still"] = stand_still_baseline(scene, num_steps)
    for name, reference in (references or {}).items():
        rollouts[name] = reference(scene, num_steps)
    return rollouts


def scene_error_records(scene, mesh_names, rollouts, horizons, gravity):
    """(method, horizon, group) -> list of error records of this scene's dynamic objects, group
    "all", ("per_shape", shape) or ("per_motion", `object_motions` class); (method, k, "all")
    with an int k for every step the rollouts cover, for the curves."""
    dynamic = ~scene.geometry.static
    shapes = np.asarray(mesh_names)[dynamic]
    motions = object_motions(scene, horizons, gravity)
    records = {}
    for method, (positions, quaternions) in rollouts.items():
        per_step = {
            step: errors_at(scene, positions, quaternions, step) for step in range(1, positions.shape[0] - 1)
        }
        for step, (translation, rotation) in per_step.items():
            records.setdefault((method, step, "all"), []).append(
                {"translation": translation, "rotation": rotation}
            )
        for horizon, steps in horizons.items():
            translation, rotation = per_step[steps]  # the rollouts reach the longest horizon
            records.setdefault((method, horizon, "all"), []).append(
                {"translation": translation, "rotation": rotation}
            )
            for group, labels in (("per_shape", shapes), ("per_motion", motions[horizon])):
                for label in np.unique(labels):
                    keep = labels == label
                    record = {"translation": translation[keep], "rotation": rotation[keep]}
                    records.setdefault((method, horizon, (group, str(label))), []).append(record)
    return records


def evaluate_scenes(simulator, data, scenes, on_scene=None, guards=None, guarded=None, references=None):
    """Metrics of the model (and the model with the guards `guarded` and the `references`, see
    method_rollouts) and the baselines on scenes of one trajectory file.

    returns {"metrics": {method: {horizon: {"all": metrics, "per_shape": {shape: metrics},
                                            "per_motion": {class: metrics}}}},
             "curves": {method: per-step lists}, "comparison": {baseline: {horizon: compare(...)}}},
    or {} when no scene covers a horizon.
    """
    all_records = {}
    for scene in scenes:
        horizons = horizon_steps(data.dt, scene.positions.shape[0])
        if not horizons:
            continue
        rollouts = method_rollouts(
            simulator, scene, max(horizons.values()), data.gravity, data.dt, guards, guarded, references
        )
        mesh_names = data.trajectories[scene.name].mesh_names
        for key, records in scene_error_records(scene, mesh_names, rollouts, horizons, data.gravity).items():
            all_records.setdefault(key, []).extend(records)
        if on_scene is not None:
            on_scene(scene)
    if not all_records:
        return {}
    metrics = nest_metrics(
        {key: records for key, records in all_records.items() if not isinstance(key[1], int)}
    )
    return {
        "metrics": metrics,
        "curves": error_curves(all_records),
        "comparison": {
            baseline: {
                horizon: compare(
                    all_records[("model", horizon, "all")], all_records[(baseline, horizon, "all")]
                )
                for horizon in metrics["model"]
            }
            for baseline in metrics
            if baseline != "model"
        },
    }


def nest_metrics(all_records):
    """{(method, horizon, group): records} -> nested metrics dict (`scene_error_records`' groups);
    each per-motion entry also has its share of the horizon's squared translation error."""
    result = {}
    for (method, horizon, group), records in sorted(all_records.items(), key=lambda item: str(item[0])):
        entry = result.setdefault(method, {}).setdefault(
            horizon, {"all": None, "per_shape": {}, "per_motion": {}}
        )
        if group == "all":
            entry["all"] = summarize_errors(records)
        else:
            entry[group[0]][group[1]] = summarize_errors(records)
    for entry in (entry for horizons in result.values() for entry in horizons.values()):
        total = entry["all"]["objects"] * entry["all"]["translation_rmse_m"] ** 2
        for metrics in entry["per_motion"].values():
            squared = metrics["objects"] * metrics["translation_rmse_m"] ** 2
            metrics["share_of_squared_translation_error"] = float(squared / total) if total > 0 else None
    return result


def error_curves(all_records):
    """{(method, step k, "all"): records} -> {method: {"step": [...], "translation_rmse_m": [...],
    "rotation_error_deg": [...], "objects": [...]}} over every step some scene reaches."""
    curves = {}
    for (method, step, _), records in all_records.items():
        if isinstance(step, int):
            curves.setdefault(method, {})[step] = summarize_errors(records)
    keys = ("translation_rmse_m", "rotation_error_deg", "objects")
    return {
        method: {"step": sorted(by_step), **{key: [by_step[k][key] for k in sorted(by_step)] for key in keys}}
        for method, by_step in curves.items()
    }


def compare(model_records, baseline_records, resamples=BOOTSTRAP_RESAMPLES, seed=BOOTSTRAP_SEED):
    """The model against a baseline on the same trajectories (records in the same order).

    Translation: RMSE ratio model / baseline; rotation: mean error difference model − baseline
    (degrees); each with a 95 % percentile bootstrap interval over trajectories, which are
    resampled together for both methods. `objects_closer`: share of objects with a smaller
    translation error than the baseline's."""
    if len(model_records) != len(baseline_records):
        raise ValueError("the model and the baseline were not evaluated on the same trajectories")
    squared = np.array(
        [
            [np.sum(m["translation"] ** 2), np.sum(b["translation"] ** 2)]
            for m, b in zip(model_records, baseline_records)
        ]
    )
    angles = np.array(
        [[np.sum(m["rotation"]), np.sum(b["rotation"])] for m, b in zip(model_records, baseline_records)]
    )
    counts = np.array([m["translation"].size for m in model_records], np.float64)
    picks = np.random.default_rng(seed).integers(0, len(counts), size=(resamples, len(counts)))
    ratios = np.sqrt(squared[picks, 0].sum(1) / np.maximum(squared[picks, 1].sum(1), 1e-300))
    differences = (angles[picks, 0].sum(1) - angles[picks, 1].sum(1)) / np.maximum(counts[picks].sum(1), 1)
    closer = np.concatenate(
        [m["translation"] < b["translation"] for m, b in zip(model_records, baseline_records)]
    )
    return {
        "translation_rmse_ratio": float(np.sqrt(squared[:, 0].sum() / max(squared[:, 1].sum(), 1e-300))),
        "translation_rmse_ratio_95": [float(v) for v in np.percentile(ratios, [2.5, 97.5])],
        "rotation_error_difference_deg": float(
            (angles[:, 0].sum() - angles[:, 1].sum()) / max(counts.sum(), 1)
        ),
        "rotation_error_difference_deg_95": [float(v) for v in np.percentile(differences, [2.5, 97.5])],
        "objects_closer": float(closer.mean()) if closer.size else None,
        "objects": int(closer.size),
        "trajectories": len(counts),
        "resamples": resamples,
    }
