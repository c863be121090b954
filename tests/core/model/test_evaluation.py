"""The model-against-baseline comparison of `evaluate` (evaluation.compare), checked against
direct computation."""

import numpy as np
import pytest

from fignetctl.core.model.evaluation import compare, summarize_errors


def records(rng, sizes, scale=1.0):
    return [{"translation": scale * rng.uniform(0, 3, n), "rotation": rng.uniform(0, 180, n)} for n in sizes]


def test_point_estimates_equal_the_pooled_metrics():
    rng = np.random.default_rng(0)
    model, baseline = records(rng, [3, 7, 1, 5]), records(rng, [3, 7, 1, 5])
    result = compare(model, baseline)
    m, b = summarize_errors(model), summarize_errors(baseline)
    assert result["translation_rmse_ratio"] == pytest.approx(
        m["translation_rmse_m"] / b["translation_rmse_m"]
    )
    assert result["rotation_error_difference_deg"] == pytest.approx(
        m["rotation_error_deg"] - b["rotation_error_deg"]
    )
    closer = np.concatenate([x["translation"] < y["translation"] for x, y in zip(model, baseline)]).mean()
    assert result["objects_closer"] == pytest.approx(closer)
    assert result["objects"] == 16 and result["trajectories"] == 4
    low, high = result["translation_rmse_ratio_95"]
    assert low <= result["translation_rmse_ratio"] <= high


def test_bootstrap_interval_matches_a_resampling_loop():
    rng = np.random.default_rng(1)
    model, baseline = records(rng, [4, 2, 6, 3, 5]), records(rng, [4, 2, 6, 3, 5])
    result = compare(model, baseline, resamples=300, seed=7)
    picks = np.random.default_rng(7).integers(0, 5, size=(300, 5))
    ratios, differences = [], []
    for pick in picks:  # resample whole trajectories, pool their objects, recompute both metrics
        m, b = summarize_errors([model[i] for i in pick]), summarize_errors([baseline[i] for i in pick])
        ratios.append(m["translation_rmse_m"] / b["translation_rmse_m"])
        differences.append(m["rotation_error_deg"] - b["rotation_error_deg"])
    np.testing.assert_allclose(result["translation_rmse_ratio_95"], np.percentile(ratios, [2.5, 97.5]))
    np.testing.assert_allclose(
        result["rotation_error_difference_deg_95"], np.percentile(differences, [2.5, 97.5])
    )


def test_a_model_at_half_the_error_everywhere_has_a_tight_interval_at_one_half():
    rng = np.random.default_rng(2)
    baseline = records(rng, [5, 5, 5])
    model = [{"translation": 0.5 * r["translation"], "rotation": r["rotation"] - 10} for r in baseline]
    result = compare(model, baseline)
    assert result["translation_rmse_ratio_95"] == pytest.approx([0.5, 0.5])
    assert result["rotation_error_difference_deg_95"] == pytest.approx([-10, -10])
    assert result["objects_closer"] == 1.0


def test_identical_methods_tie():
    rng = np.random.default_rng(3)
    same = records(rng, [2, 8])
    result = compare(same, same)
    assert result["translation_rmse_ratio"] == 1.0 and result["translation_rmse_ratio_95"] == [1.0, 1.0]
    assert result["objects_closer"] == 0.0


def test_unpaired_records_are_refused():
    rng = np.random.default_rng(4)
    with pytest.raises(ValueError, match="same trajectories"):
        compare(records(rng, [2, 3]), records(rng, [2]))


GRAVITY = (0.0, 0.0, -10.0)


def _box_scene(bounce_speed=None):
    """box_drop_file's box falling freely and spinning, or with `bounce_speed`
    bouncing_box_file's box bouncing at that speed at frame 6; its scene and its file."""
    import dataclasses

    from fignetctl.core.model.scene_data import TRAINING_STATIC_REACH, scenes_from_data
    from fignetctl.core.model.training import simulator_config_for
    from tests.conftest import bouncing_box_file, box_drop_file

    if bounce_speed is None:
        data = box_drop_file(frames=12, spin=3.0, height=2.0)
    else:
        data = bouncing_box_file(frames=12, impact=6, speed=bounce_speed)
    config = dataclasses.replace(
        simulator_config_for("fignet-star", "tiny", 0.1, state="velocities"), gravity=GRAVITY, dt=data.dt
    )
    (scene,) = scenes_from_data(data, config, TRAINING_STATIC_REACH)
    return scene, data


@pytest.mark.parametrize(
    "bounce_speed, steps, motion",
    [
        (None, 10, "calm"),  # free fall with spin, every step
        (3.0, 4, "calm"),  # the bounce (frame 5 -> 6) is past the horizon
        (3.0, 5, "impact"),  # 6 m/s in a frame of 1/60 s: 36 g beyond gravity
        (0.3, 8, "contact"),  # 0.6 m/s in a frame: 3.6 g, a change but not an impact
    ],
)
def test_object_motions_is_the_worst_step_within_the_horizon(bounce_speed, steps, motion):
    from fignetctl.core.model.evaluation import object_motions

    scene, _ = _box_scene(bounce_speed)
    motions = object_motions(scene, {"horizon": steps, "longest": 10}, GRAVITY)
    assert list(motions["horizon"]) == [motion]  # the box; the floor is static


def test_a_box_at_rest_is_calm():
    import dataclasses

    from fignetctl.core.model.evaluation import object_motions

    scene, _ = _box_scene()
    resting = dataclasses.replace(
        scene,
        positions=np.repeat(scene.positions[:1], len(scene.positions), 0),
        quaternions=np.repeat(scene.quaternions[:1], len(scene.quaternions), 0),
        velocities=np.zeros_like(scene.velocities),
        angular_velocities=np.zeros_like(scene.angular_velocities),
    )
    assert list(object_motions(resting, {"1 s": 10}, GRAVITY)["1 s"]) == ["calm"]


def test_per_motion_metrics_pool_each_class_and_share_the_squared_error():
    from fignetctl.core.model.evaluation import nest_metrics, scene_error_records

    all_records = {}
    for offset, bounce_speed in ((0.1, None), (0.3, 3.0), (0.2, 0.3)):
        scene, data = _box_scene(bounce_speed)
        shifted = (scene.positions + offset * np.array([1.0, 0.0, 0.0]), scene.quaternions)
        rollouts = {"model": shifted, "truth": (scene.positions, scene.quaternions)}
        horizons = {"short": 4, "long": 8}
        mesh_names = data.trajectories["00000"].mesh_names
        for key, records in scene_error_records(scene, mesh_names, rollouts, horizons, GRAVITY).items():
            all_records.setdefault(key, []).extend(records)
    metrics = nest_metrics({key: value for key, value in all_records.items() if isinstance(key[1], str)})
    long, short = metrics["model"]["long"], metrics["model"]["short"]
    assert set(long["per_motion"]) == {"calm", "contact", "impact"}
    for motion, offset in (("calm", 0.1), ("impact", 0.3), ("contact", 0.2)):
        assert long["per_motion"][motion]["translation_rmse_m"] == pytest.approx(offset, rel=1e-5)
        assert long["per_motion"][motion]["share_of_squared_translation_error"] == pytest.approx(
            offset**2 / (0.1**2 + 0.3**2 + 0.2**2), rel=1e-5
        )
    # within 4 steps no box has met the floor yet: all three are calm, the whole error theirs
    assert set(short["per_motion"]) == {"calm"} and short["per_motion"]["calm"]["objects"] == 3
    assert short["per_motion"]["calm"]["share_of_squared_translation_error"] == pytest.approx(1.0)
    assert long["per_shape"]["box"]["objects"] == 3 and long["all"]["objects"] == 3
    # a method without error has no share to give
    assert metrics["truth"]["long"]["per_motion"]["calm"]["share_of_squared_translation_error"] is None
